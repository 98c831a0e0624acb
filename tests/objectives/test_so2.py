"""Tests for SO2's ensemble critic loss (policy-smoothed targets, per-member regression)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded, Unbounded
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import SoftUpdate
from toy import tanh_normal_actor

from torchrl_dual.objectives.so2 import TARGET_REDUCTIONS, SO2QLoss

OBS, ACT, E = 3, 2, 4


# ----------------------------------------------------------------------------- factories
class _FixedActor(nn.Module):
    """``a = tanh(W s)`` and a known ``log π = −Σ s``: deterministic, so targets are exact."""

    def __init__(self) -> None:
        super().__init__()
        self.linear = nn.Linear(OBS, ACT)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return torch.tanh(self.linear(observation)), -observation.sum(-1)


class _ConstantActor(nn.Module):
    def __init__(self, action: torch.Tensor) -> None:
        super().__init__()
        self.action = action

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return self.action.expand(*observation.shape[:-1], -1)


def _mock_actor(seed: int = 0) -> TensorDictModule:
    torch.manual_seed(seed)
    return TensorDictModule(
        _FixedActor(), in_keys=["observation"], out_keys=["action", "action_log_prob"]
    )


def _mock_sac_actor(seed: int = 0) -> ProbabilisticActor:
    torch.manual_seed(seed)
    return tanh_normal_actor(OBS, ACT, return_log_prob=True)


def _mock_qvalue(seed: int = 0, width: int = 8) -> ValueOperator:
    torch.manual_seed(seed)
    return ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[width]),
        in_keys=["observation", "action"],
    )


def _mock_loss(actor=None, **kwargs) -> SO2QLoss:
    kwargs.setdefault("action_spec", Bounded(-1.0, 1.0, shape=(ACT,)))
    kwargs.setdefault("num_qvalue_nets", E)
    return SO2QLoss(actor if actor is not None else _mock_actor(), _mock_qvalue(), **kwargs)


def _mock_batch(batch: int = 16, *, seed: int = 0, terminal_every: int = 4) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    terminated = torch.zeros(batch, 1, dtype=torch.bool)
    terminated[::terminal_every] = True
    return TensorDict(
        {
            "observation": torch.randn(batch, OBS, generator=gen),
            "action": torch.rand(batch, ACT, generator=gen) * 2 - 1,
            "next": {
                "observation": torch.randn(batch, OBS, generator=gen),
                "reward": torch.randn(batch, 1, generator=gen),
                "terminated": terminated,
            },
        },
        [batch],
    )


def _member_q(loss: SO2QLoss, params, k: int, obs: torch.Tensor, act: torch.Tensor):
    """``Q_k(s, a)`` by a plain call of member ``k`` (no vmap)."""
    td = TensorDict(observation=obs, action=act, batch_size=obs.shape[:-1])
    with params[k].to_module(loss.qvalue_network):
        return loss.qvalue_network(td)["state_action_value"].squeeze(-1)


# ----------------------------------------------------------------------------- target
@pytest.mark.parametrize("reduction", TARGET_REDUCTIONS)
def test_ensemble_target_matches_a_loop_over_members(reduction):
    gamma, alpha, sigma, clip = 0.9, 0.2, 0.3, 0.4
    loss = _mock_loss(
        target_reduction=reduction,
        next_action="mean",
        entropy_coef=alpha,
        gamma=gamma,
        policy_noise=sigma,
        noise_clip=clip,
    )
    # targets differ from the online ensemble, as after some updates
    loss.target_qvalue_network_params.data.add_(
        0.1 * torch.randn_like(loss.target_qvalue_network_params.data)
    )
    batch = _mock_batch()
    torch.manual_seed(123)
    target = loss.target_value(batch)

    torch.manual_seed(123)
    nxt = batch["next"]
    mean_action, log_prob = loss.actor_network.module(nxt["observation"])
    noise = (torch.randn(mean_action.shape) * sigma).clamp(-clip, clip)
    smoothed = (mean_action + noise).clamp(-1.0, 1.0)
    params = loss.target_qvalue_network_params
    members = torch.stack(
        [_member_q(loss, params, k, nxt["observation"], smoothed) for k in range(E)]
    )
    next_q = {"independent": members, "min": members.min(0).values, "mean": members.mean(0)}
    not_terminal = 1.0 - nxt["terminated"].squeeze(-1).float()
    expected = nxt["reward"].squeeze(-1) + gamma * not_terminal * (
        next_q[reduction] - alpha * log_prob
    )

    assert target.shape == ((E, 16) if reduction == "independent" else (16,))
    torch.testing.assert_close(target, expected)
    # terminal transitions bootstrap nothing
    torch.testing.assert_close(
        target[..., ::4], nxt["reward"].squeeze(-1)[::4].expand_as(target[..., ::4])
    )


def test_qvalue_loss_is_the_mean_over_members_of_each_members_squared_error():
    loss = _mock_loss(next_action="mean", policy_noise=0.0)
    batch = _mock_batch()
    out = loss(batch.clone())
    target = loss.target_value(batch)  # no noise: deterministic
    params = loss.qvalue_network_params
    q = torch.stack(
        [_member_q(loss, params, k, batch["observation"], batch["action"]) for k in range(E)]
    )
    torch.testing.assert_close(out["loss_qvalue"], (q - target).pow(2).mean())


# ----------------------------------------------------------------------------- smoothing
def test_smoothing_noise_is_clipped_as_configured_and_actions_stay_in_the_box():
    low, high = torch.tensor([0.0, -2.0]), torch.tensor([1.0, 2.0])
    a = torch.tensor([0.95, 0.0])
    actor = TensorDictModule(_ConstantActor(a), in_keys=["observation"], out_keys=["action"])
    loss = _mock_loss(
        actor, action_spec=Bounded(low, high, shape=(ACT,)), policy_noise=10.0, noise_clip=0.2
    )
    torch.manual_seed(0)
    smoothed, _ = loss.target_action(_mock_batch(4000)["next"])
    assert bool(((smoothed >= low) & (smoothed <= high)).all())
    noise = smoothed - a
    assert bool((noise.abs() <= 0.2 + 1e-6).all())
    # σ ≫ c: almost every draw is clipped to ±c (dim 1, far from the box) ...
    assert (noise[:, 1].abs() - 0.2).abs().lt(1e-6).float().mean() > 0.95
    # ... and near the upper bound the box clips ã' to exactly 1.0
    assert smoothed[:, 0].eq(1.0).float().mean() > 0.4

    # small σ, loose clip: the noise is N(0, σ²)
    loss = _mock_loss(
        actor, action_spec=Bounded(low, high, shape=(ACT,)), policy_noise=0.1, noise_clip=10.0
    )
    torch.manual_seed(1)
    smoothed, _ = loss.target_action(_mock_batch(4000)["next"])
    assert abs(float((smoothed[:, 1] - a[1]).std()) - 0.1) < 0.01


def test_sac_actor_targets_use_a_sample_and_its_log_probability():
    loss = _mock_loss(_mock_sac_actor(), entropy_coef=0.2, policy_noise=0.0)
    batch = _mock_batch()
    torch.manual_seed(0)
    first, log_prob = loss.target_action(batch["next"])
    second, _ = loss.target_action(batch["next"])
    assert not torch.allclose(first, second)  # a' is sampled, not the mean
    assert log_prob.shape == (16,) and torch.isfinite(log_prob).all()
    out = loss(batch)
    assert torch.isfinite(out["loss_qvalue"])


# ----------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("sac", [False, True])
def test_gradients_reach_only_the_q_ensemble(sac):
    actor = _mock_sac_actor() if sac else _mock_actor()
    loss = _mock_loss(actor, entropy_coef=0.2 if sac else 0.0)
    batch = _mock_batch()
    before = batch.clone()
    loss(batch)["loss_qvalue"].backward()
    for name, param in loss.qvalue_network_params.items(True, True):
        assert param.grad is not None and param.grad.abs().sum() > 0, name
    assert all(p.grad is None for p in actor.parameters())
    assert all(p.grad is None for p in loss.target_qvalue_network_params.values(True, True))
    assert [n for n, _ in loss.named_parameters()] == [
        f"qvalue_network_params.{'.'.join(k)}" for k in loss.qvalue_network_params.keys(True, True)
    ]
    assert (batch.select(*before.keys(True, True)) == before).all()  # input unchanged


def test_actor_objective_q_is_the_min_over_members_and_trains_only_the_action():
    loss = _mock_loss()
    batch = _mock_batch()
    action = batch["action"].clone().requires_grad_(True)
    q_min = loss.q_value(batch["observation"], action)
    params = loss.qvalue_network_params
    members = torch.stack(
        [_member_q(loss, params, k, batch["observation"], batch["action"]) for k in range(E)]
    )
    torch.testing.assert_close(q_min, members.min(0).values)
    torch.testing.assert_close(
        loss.q_value(batch["observation"], action, reduction="mean"), members.mean(0)
    )
    q_min.sum().backward()
    assert action.grad is not None and action.grad.abs().sum() > 0
    assert all(p.grad is None for p in loss.parameters())


# ----------------------------------------------------------------------------- learning
def test_loss_decreases_on_a_fixed_toy_regression():
    """Terminal transitions: each member regresses ``Q(s, a) → r = sin(s_0) + a_0``."""
    loss = SO2QLoss(
        _mock_actor(),
        _mock_qvalue(width=32),
        action_spec=Bounded(-1.0, 1.0, shape=(ACT,)),
        num_qvalue_nets=E,
    )
    batch = _mock_batch(128, terminal_every=1)
    batch["next", "reward"] = batch["observation"][:, :1].sin() + batch["action"][:, :1]
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-2)
    updater = SoftUpdate(loss, tau=0.05)
    history = []
    for _ in range(300):
        value = loss(batch)["loss_qvalue"]
        optimizer.zero_grad()
        value.backward()
        optimizer.step()
        updater.step()
        history.append(float(value.detach()))
    assert history[-1] < 0.05 * history[0]


def test_soft_update_moves_the_targets_toward_the_ensemble():
    loss = _mock_loss()
    updater = SoftUpdate(loss, tau=0.25)
    updater.init_()  # targets start as copies of the ensemble
    old = loss.target_qvalue_network_params.data.clone()
    assert ((old - loss.qvalue_network_params.data).abs() == 0).all()
    with torch.no_grad():
        loss.qvalue_network_params.data.add_(1.0)
    updater.step()
    new = loss.qvalue_network_params.data
    expected = old * 0.75 + new * 0.25
    assert ((loss.target_qvalue_network_params.data - expected).abs() < 1e-6).all()


# ----------------------------------------------------------------------------- errors
def test_in_keys_list_what_the_loss_reads():
    assert _mock_loss().in_keys == [
        "observation",
        "action",
        ("next", "observation"),
        ("next", "reward"),
        ("next", "terminated"),
    ]


def test_bad_settings_and_missing_entries_name_the_fix():
    with pytest.raises(ValueError, match="choose one of"):
        _mock_loss(target_reduction="max")
    with pytest.raises(ValueError, match="choose one of"):
        _mock_loss(next_action="mode")
    with pytest.raises(ValueError, match="bounded"):
        _mock_loss(action_spec=Unbounded(shape=(ACT,)))
    batch = _mock_batch()
    del batch["next", "reward"]
    with pytest.raises(KeyError, match="set_keys"):
        _mock_loss()(batch)
    no_log_prob = TensorDictModule(
        MLP(in_features=OBS, out_features=ACT, num_cells=[4]),
        in_keys=["observation"],
        out_keys=["action"],
    )
    with pytest.raises(KeyError, match="log_prob"):
        _mock_loss(no_log_prob, entropy_coef=0.2)(_mock_batch())


def test_make_value_estimator_sets_gamma_as_torchrl_losses_do():
    """Generic TorchRL loops call ``loss.make_value_estimator(gamma=...)``: SO2's TD(0)
    target takes it (and refuses other estimators or hyperparameters by name)."""
    from torchrl.objectives.utils import ValueEstimators

    loss, batch = _mock_loss(), _mock_batch()
    torch.manual_seed(0)
    before = loss(batch.clone())["loss_qvalue"]
    assert loss.make_value_estimator(ValueEstimators.TD0, gamma=0.0) is loss
    assert loss.gamma == 0.0
    torch.manual_seed(0)
    assert not torch.allclose(loss(batch.clone())["loss_qvalue"], before)  # γ reached y
    with pytest.raises(NotImplementedError, match="TD0"):
        loss.make_value_estimator(ValueEstimators.TDLambda)
    with pytest.raises(TypeError, match="gamma only"):
        loss.make_value_estimator(lmbda=0.9)


def test_the_loss_compiles_without_a_graph_break():
    loss, batch = _mock_loss(), _mock_batch()
    torch._dynamo.reset()
    out = torch.compile(loss, fullgraph=True, backend="eager")(batch)
    assert torch.isfinite(out["loss_qvalue"])
