"""Tests for SO2's ensemble critic loss (policy-smoothed targets, per-member regression)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded, Composite, Unbounded
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


# ----------------------------------------------------------------------------- loss forms
def _terminal_batch(batch: int = 16, *, scale: float = 1.0) -> TensorDict:
    """Every transition terminal: the target is the reward itself, ``y = r``."""
    td = _mock_batch(batch, terminal_every=1)
    td["next", "reward"] = td["next", "reward"] * scale
    return td


def _members(loss: SO2QLoss, batch: TensorDict) -> torch.Tensor:
    """``Q_k(s, a)`` for every member by a loop, ``[E, B]``."""
    params = loss.qvalue_network_params
    return torch.stack(
        [
            _member_q(loss, params, k, batch["observation"], batch["action"])
            for k in range(loss.qvalue_network_params.shape[0])
        ]
    )


def _smooth_l1(d: torch.Tensor) -> torch.Tensor:
    """Huber with ``β = 1``: ``d²/2`` for ``|d| < 1``, else ``|d| − 1/2``."""
    return torch.where(d.abs() < 1, 0.5 * d.square(), d.abs() - 0.5)


@pytest.mark.parametrize("loss_function", ["l2", "l1", "smooth_l1"])
def test_each_loss_function_is_averaged_over_members_and_batch(loss_function):
    """``L = mean_k mean_b ℓ(Q_k(s, a) − y)`` with ``ℓ`` the squared, absolute or Huber
    error (rewards scaled up so that Huber's two branches both occur)."""
    loss = _mock_loss(loss_function=loss_function)
    batch = _terminal_batch(scale=3.0)
    diff = _members(loss, batch) - batch["next", "reward"].squeeze(-1)
    assert bool((diff.abs() < 1).any()) and bool((diff.abs() > 1).any())
    per_element = {"l2": diff.square(), "l1": diff.abs(), "smooth_l1": _smooth_l1(diff)}
    torch.testing.assert_close(loss(batch)["loss_qvalue"], per_element[loss_function].mean())


def test_reduction_none_and_sum_keep_the_per_transition_mean_over_members():
    batch = _terminal_batch()
    loss = _mock_loss(reduction="none")
    per_sample = (_members(loss, batch) - batch["next", "reward"].squeeze(-1)).square().mean(0)
    out = loss(batch)["loss_qvalue"]
    assert out.shape == (16,)
    torch.testing.assert_close(out, per_sample)
    loss = _mock_loss(reduction="sum")
    torch.testing.assert_close(loss(batch)["loss_qvalue"], per_sample.sum())


def test_diagnostics_report_the_mean_q_and_the_mean_target():
    loss, batch = _mock_loss(), _terminal_batch()
    out = loss(batch)
    assert sorted(out.keys()) == ["loss_qvalue", "state_action_value", "target_value"]
    assert out.batch_size == torch.Size([])
    torch.testing.assert_close(out["state_action_value"], _members(loss, batch).mean())
    torch.testing.assert_close(out["target_value"], batch["next", "reward"].mean())


def test_a_collector_mask_drops_padded_transitions_from_the_mean():
    """TorchRL's ``("collector", "mask")`` marks padding: masked transitions do not count."""
    loss, batch = _mock_loss(), _terminal_batch()
    mask = torch.arange(16) % 3 != 0
    batch["collector", "mask"] = mask
    per_sample = (_members(loss, batch) - batch["next", "reward"].squeeze(-1)).square().mean(0)
    torch.testing.assert_close(loss(batch)["loss_qvalue"], per_sample[mask].mean())


def test_a_single_member_ensemble_regresses_on_its_own_target():
    loss, batch = _mock_loss(num_qvalue_nets=1), _terminal_batch()
    assert loss.num_qvalue_nets == 1 and loss.qvalue_network_params.shape[0] == 1
    q = _members(loss, batch)
    assert q.shape == (1, 16)
    expected = (q[0] - batch["next", "reward"].squeeze(-1)).square().mean()
    torch.testing.assert_close(loss(batch)["loss_qvalue"], expected)


def test_zero_noise_clip_leaves_the_next_action_unperturbed():
    a = torch.tensor([0.3, -0.4])
    actor = TensorDictModule(_ConstantActor(a), in_keys=["observation"], out_keys=["action"])
    loss = _mock_loss(actor, policy_noise=5.0, noise_clip=0.0)
    smoothed, log_prob = loss.target_action(_mock_batch(32)["next"])
    torch.testing.assert_close(smoothed, a.expand(32, ACT))
    torch.testing.assert_close(log_prob, torch.zeros(32))  # entropy_coef = 0


def test_a_composite_action_spec_gives_its_action_box():
    """``ã'`` is clipped to the box of ``Composite(action=Bounded(low, high))``."""
    low, high = torch.tensor([-1.0, 0.5]), torch.tensor([1.0, 2.0])
    a = torch.tensor([3.0, -3.0])
    actor = TensorDictModule(_ConstantActor(a), in_keys=["observation"], out_keys=["action"])
    spec = Composite(action=Bounded(low, high, shape=(ACT,)))
    loss = _mock_loss(actor, action_spec=spec, policy_noise=0.0)
    smoothed, _ = loss.target_action(_mock_batch(8)["next"])
    torch.testing.assert_close(smoothed, torch.tensor([1.0, 0.5]).expand(8, ACT))


def test_q_value_of_one_unbatched_state_action_is_the_min_over_members():
    loss, batch = _mock_loss(), _mock_batch()
    obs, act = batch["observation"][0], batch["action"][0]
    value = loss.q_value(obs, act)
    assert value.shape == ()
    torch.testing.assert_close(value, _members(loss, batch)[:, 0].min())


def test_members_draw_their_own_dropout_masks():
    """A Q network with dropout: in training mode each member samples its own mask, so
    identical members disagree; in evaluation mode they agree."""
    torch.manual_seed(0)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[64], dropout=0.5),
        in_keys=["observation", "action"],
    )
    loss = SO2QLoss(
        _mock_actor(), qvalue, action_spec=Bounded(-1.0, 1.0, shape=(ACT,)), num_qvalue_nets=E
    )
    params = loss.qvalue_network_params.data.clone()
    params.apply_(lambda p: p.copy_(p[:1].expand_as(p)))  # every member = member 0
    batch = _mock_batch()
    values = loss.ensemble_values(batch, params)
    assert values.shape == (E, 16)
    assert not torch.allclose(values[0], values[1])
    loss.qvalue_network.eval()
    values = loss.ensemble_values(batch, params)
    torch.testing.assert_close(values[1:], values[:1].expand(E - 1, 16))


def test_documented_defaults():
    loss = SO2QLoss(_mock_actor(), _mock_qvalue(), action_spec=Bounded(-1.0, 1.0, shape=(ACT,)))
    assert loss.num_qvalue_nets == 10 and loss.qvalue_network_params.shape[0] == 10
    assert (loss.policy_noise, loss.noise_clip) == (0.3, 0.6)
    assert (loss.target_reduction, loss.next_action) == ("independent", "sample")
    assert (loss.entropy_coef, loss.gamma) == (0.0, 0.99)
    assert (loss.loss_function, loss.reduction) == ("l2", "mean")


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


@pytest.mark.parametrize(
    ("name", "value"),
    [("target_reduction", "max"), ("next_action", "mode"), ("loss_function", "huber")],
)
def test_an_unknown_option_is_named_with_its_choices(name, value):
    with pytest.raises(ValueError, match=f"^Unknown {name} '{value}'; choose one of"):
        _mock_loss(**{name: value})


def test_out_of_range_settings_are_refused_by_name():
    with pytest.raises(ValueError, match="num_qvalue_nets must be >= 1, got 0"):
        _mock_loss(num_qvalue_nets=0)
    for noise, clip in ((-0.1, 0.5), (0.3, -0.1)):
        with pytest.raises(ValueError, match="policy_noise and noise_clip must be >= 0"):
            _mock_loss(policy_noise=noise, noise_clip=clip)
    with pytest.raises(
        ValueError,
        match=r"^SO2QLoss clips the smoothed action to the action box and needs a bounded "
        r"action_spec \(torchrl\.data\.Bounded\); got UnboundedContinuous\.$",
    ):
        _mock_loss(action_spec=Unbounded(shape=(ACT,)))
    with pytest.raises(ValueError, match="^Unknown reduction 'max'; choose one of"):
        _mock_loss().q_value(torch.zeros(2, OBS), torch.zeros(2, ACT), reduction="max")


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
    with pytest.raises(
        NotImplementedError,
        match=r"Call make_value_estimator\(\) or make_value_estimator\(ValueEstimators\.TD0\)\.$",
    ):
        loss.make_value_estimator(ValueEstimators.TDLambda)
    with pytest.raises(TypeError, match="gamma only"):
        loss.make_value_estimator(lmbda=0.9)


def test_the_loss_compiles_without_a_graph_break():
    loss, batch = _mock_loss(), _mock_batch()
    torch._dynamo.reset()
    out = torch.compile(loss, fullgraph=True, backend="eager")(batch)
    assert torch.isfinite(out["loss_qvalue"])


def test_vmap_randomness_reaches_the_ensemble_evaluation():
    """TorchRL's rule: ``"different"`` for a Q network with dropout (each member its own
    mask), settable; ``"error"`` then makes vmap refuse the random op, so the setting is the
    one the ensemble runs with."""
    torch.manual_seed(0)
    dropout_q = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8], dropout=0.5),
        in_keys=["observation", "action"],
    )
    loss = SO2QLoss(_mock_actor(), dropout_q, action_spec=Bounded(-1.0, 1.0, shape=(ACT,)),
                    num_qvalue_nets=E)  # fmt: skip
    assert loss.vmap_randomness == "different"
    assert torch.isfinite(loss(_mock_batch())["loss_qvalue"])
    loss.set_vmap_randomness("error")
    with pytest.raises(RuntimeError, match="randomness"):
        loss(_mock_batch())
