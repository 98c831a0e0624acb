"""The AWR baselines' actor (``make_iql_actor``, ``actor.distribution``; issue 27).

What made ``algo=iql`` a quarter of d3rlpy's IQL offline on U-maze: 61 % of the data's
action components lie on a face of the box, where a ``TanhNormal``'s log-density reads
``atanh`` of a clamped ±(1 − ε) (≈ ±8 before the tanh), so the fit of such an action is
dominated by the clamp. CORL's and d3rlpy's actor, ``N(tanh mean, state-independent σ)``
(``gaussian``, now the default), fits the data's mean in the action space. The first
test pins exactly that difference on a one-state data set with a closed-form answer.
"""

from __future__ import annotations

import math

import pytest
import torch
from recipe_runner import CONFIG_DIR
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.recipe import ConfigError, compose_checked
from torchrl_dual.recipe.algos.iql import make_iql_actor
from torchrl_dual.recipe.settings.baselines import MLPActorSettings


def _actor(distribution: str, low: float = -1.0, high: float = 1.0):
    torch.manual_seed(0)
    settings = MLPActorSettings(hidden=16, depth=1, lr=3e-4)
    spec = Bounded(low, high, shape=(1,))
    return make_iql_actor(settings, 3, spec, distribution=distribution)


def _fit(actor, observation, actions, steps=600):
    """Maximum likelihood (AWR with unit weights) on one state's actions, as IQLLoss's
    actor loss does it through ``get_dist``; returns the deterministic action."""
    optimizer = torch.optim.Adam(actor.parameters(), lr=3e-2)
    data = TensorDict({"observation": observation.expand(len(actions), 3)}, [len(actions)])
    for _ in range(steps):
        loss = -actor.get_dist(data.clone()).log_prob(actions).mean()
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        return actor(TensorDict({"observation": observation}, []))["action"]


def test_the_gaussian_actor_fits_the_action_mean_where_tanh_normal_is_pulled_to_the_face():
    """70 % of the actions at 0.2, 30 % on the face −1. The Gaussian's maximum-likelihood
    mean is the data's mean, 0.7·0.2 − 0.3 = −0.16; the TanhNormal's deterministic action
    is tanh of the mean of atanh(clamped a), which the face's ≈ −8 drags below −0.9."""
    observation = torch.tensor([0.3, -0.2, 0.5])
    actions = torch.tensor([[0.2]] * 7 + [[-1.0]] * 3)
    gaussian = _fit(_actor("gaussian"), observation, actions)
    tanh_normal = _fit(_actor("tanh_normal"), observation, actions)
    assert gaussian.item() == pytest.approx(-0.16, abs=0.02)
    assert tanh_normal.item() < -0.9


def test_the_gaussian_log_prob_on_a_face_is_the_normal_density_of_the_tanh_mean():
    """By hand: ``log N(a; c + r tanh(f(s)), σ²)`` summed over dimensions, finite at ±1."""
    actor = _actor("gaussian", low=-2.0, high=2.0)
    data = TensorDict({"observation": torch.randn(4, 3)}, [4])
    dist = actor.get_dist(data)
    raw = actor.module[0].module[0](data["observation"])  # the MLP's output f(s)
    mean = 2.0 * torch.tanh(raw)
    sigma = dist.base_dist.scale
    assert torch.allclose(sigma, torch.ones_like(sigma))  # state-independent, initial σ = 1
    action = torch.tensor([[2.0], [-2.0], [0.5], [2.0]])
    by_hand = (
        -0.5 * ((action - mean) / sigma) ** 2 - torch.log(sigma) - 0.5 * math.log(2 * math.pi)
    ).sum(-1)
    assert torch.allclose(dist.log_prob(action), by_hand, atol=1e-5)


def test_gaussian_draws_are_projected_onto_the_box_and_the_deterministic_action_is_the_mean():
    actor = _actor("gaussian", low=-0.1, high=0.1)  # σ = 1 on a narrow box: most draws leave it
    data = TensorDict({"observation": torch.randn(256, 3)}, [256])
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        drawn = actor(data.clone())["action"]
    assert drawn.abs().max() <= 0.1 and (drawn.abs() == 0.1).float().mean() > 0.5
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        out = actor(data.clone())
    assert torch.equal(out["action"], out["loc"]) and out["action"].abs().max() < 0.1


def test_an_unknown_actor_distribution_is_a_config_error_listing_the_choices(tmp_path):
    with pytest.raises(ConfigError, match="gaussian, tanh_normal"):
        compose_checked(
            CONFIG_DIR, ["algo=iql", "actor.distribution=beta", f"output_dir={tmp_path}"]
        )
    with pytest.raises(ValueError, match="unknown actor distribution 'beta'"):
        _actor("beta")


def test_iql_edis_and_iql_la_default_to_the_gaussian_actor(tmp_path):
    out = f"output_dir={tmp_path}"
    for algo in ("iql", "edis", "iql_la"):
        cfg = compose_checked(CONFIG_DIR, [f"algo={algo}", out])
        assert cfg.actor.distribution == "gaussian", algo
