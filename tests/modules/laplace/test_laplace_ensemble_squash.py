"""Tests for the Laplace ensemble over a squashed ``LinearHeadActor`` (``TanhSquash``):
Eq. 9's mean and variance over the squashed members, a posterior over the pre-squash head."""

from __future__ import annotations

import torch
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import ENSEMBLE_ACTION_DIM as ACT
from toy import assert_all_close
from toy import ensemble_observation_td as _obs_td
from toy import ensemble_training_data as _training_data
from toy import fitted_ensemble as _fitted_policy

from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor
from torchrl_dual.modules.actors.last_layer_actor import TanhSquash


# ----------------------------------------------------------------------------- squashed actor
def _squashed_pair(num_samples: int = 6):
    """The same fitted ensemble twice: with ``TanhSquash(low, high)`` and without (shared
    weights, posterior and draws); ``(squashed, affine, low, high)``."""
    low, high = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0])
    affine = _fitted_policy("linear_head", None, num_samples=num_samples)
    layers = nn.Sequential(*affine.actor.trunk, affine.actor.head)  # the same weights
    squashed_actor = LinearHeadActor(layers, ACT, squash=TanhSquash(low, high))
    squashed = LaplaceEnsembleActor(squashed_actor, num_samples=num_samples)
    squashed.load_state_dict(affine.state_dict(), strict=False)  # σ̄, posterior, draws
    return squashed, affine, low, high


def test_squashed_members_are_the_squash_of_the_affine_members():
    squashed, affine, low, high = _squashed_pair()
    assert affine.actor.squash is None and squashed.actor.head is affine.actor.head
    observation = _obs_td(9, scale=3.0)["observation"]
    with torch.no_grad():
        pre = affine.member_actions(observation)
        members = squashed.member_actions(observation)
    torch.testing.assert_close(members, low + (high - low) * (torch.tanh(pre) + 1) / 2)
    assert (members >= low).all() and (members <= high).all()


def test_squashed_loc_and_epistemic_are_the_mean_and_variance_of_the_squashed_members():
    squashed, affine, low, high = _squashed_pair(num_samples=7)
    td = _obs_td(6, scale=3.0)
    with torch.no_grad():
        out = squashed(td.clone())
        members = squashed.member_actions(td["observation"])
        pre_loc = affine(td.clone())["loc"]
    torch.testing.assert_close(out["loc"], members.mean(0))
    torch.testing.assert_close(out["epistemic_variance"], members.var(0, correction=0))
    torch.testing.assert_close(out["scale"] ** 2, out["epistemic_variance"] + squashed.actor.std**2)
    assert (out["epistemic_variance"] > 0).all()
    # Eq. 9 averages actions: the mean of tanh is not tanh of the mean
    assert not torch.allclose(out["loc"], low + (high - low) * (torch.tanh(pre_loc) + 1) / 2)


def test_a_squashed_actor_has_the_same_posterior_and_a_squashed_map_action():
    squashed, affine, low, high = _squashed_pair()
    data = _training_data()
    squashed.fit_laplace([data])
    affine.fit_laplace([data])
    # the Gram matrix, λ, θ* and σ_head: the squash does not enter the posterior
    got, expected = squashed.laplace.state_dict(), affine.laplace.state_dict()
    names = [n for n, v in expected.items() if isinstance(v, torch.Tensor)]
    assert {"G_raw", "theta_map", "noise_variance", "prior_precision"} <= set(names)
    assert_all_close([got[n] for n in names], [expected[n] for n in names])
    observation = _obs_td(5)["observation"]
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        action = squashed(_obs_td(5))["action"]
        map_pre = affine(_obs_td(5))["action"]
    torch.testing.assert_close(action, squashed.actor(observation))
    torch.testing.assert_close(action, low + (high - low) * (torch.tanh(map_pre) + 1) / 2)
    zero = LaplaceEnsembleActor(squashed.actor, num_samples=0, sample_action=False)
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        torch.testing.assert_close(zero(_obs_td(5))["loc"], action)


def test_gradients_reach_the_head_through_the_squash_of_each_member():
    squashed, affine, low, high = _squashed_pair(num_samples=3)
    observation = _obs_td(4, scale=2.0)["observation"]
    squashed.member_actions(observation).sum().backward()
    pre = affine.member_actions(observation).detach()  # [M, B, A]
    # d/db of Σ_m Σ_b c + r tanh(b + ...) = Σ_m Σ_b r (1 - tanh²), r = (high - low) / 2
    expected = ((high - low) / 2 * (1 - torch.tanh(pre) ** 2)).sum((0, 1))
    torch.testing.assert_close(squashed.actor.head.bias.grad, expected)
