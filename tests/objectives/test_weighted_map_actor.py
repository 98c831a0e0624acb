"""Tests for the weighted MAP actor loss of DUAL (Eq. 7)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded, Unbounded
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import IQLLoss
from toy import mlp_by_hand, tanh_normal_actor

from torchrl_dual.modules import LinearHeadActor, PlannerActor
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS, WeightedMAPActorLoss

OBS, ACT = 3, 2
BOX = Bounded(-1.0, 1.0, shape=(ACT,))


# ----------------------------------------------------------------------------- factories
def _mock_actor(obs_dim: int = OBS, action_dim: int = ACT, *, seed: int = 0) -> LinearHeadActor:
    torch.manual_seed(seed)
    return LinearHeadActor(
        MLP(in_features=obs_dim, out_features=action_dim, num_cells=[8]), action_dim
    )


def _mock_iql(obs_dim: int = OBS, action_dim: int = ACT, *, seed: int = 0) -> IQLLoss:
    """A real TorchRL ``IQLLoss`` with tiny ``ValueOperator`` Q (twin) and V networks."""
    torch.manual_seed(seed)
    policy = tanh_normal_actor(obs_dim, action_dim)
    qvalue = ValueOperator(
        MLP(in_features=obs_dim + action_dim, out_features=1, num_cells=[8]),
        in_keys=["observation", "action"],
    )
    value = ValueOperator(
        MLP(in_features=obs_dim, out_features=1, num_cells=[8]), in_keys=["observation"]
    )
    return IQLLoss(policy, qvalue, value, num_qvalue_nets=2)


def _mock_batch(
    batch: int = 16, obs_dim: int = OBS, action_dim: int = ACT, *, seed: int = 0
) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "observation": torch.randn(batch, obs_dim, generator=gen),
            "action": torch.rand(batch, action_dim, generator=gen) * 2 - 1,
        },
        [batch],
    )


class _LinearCritic(nn.Module):
    """A fake critic ``Q(s, a) = Σ_j a_j`` (or ``V(s) = 0``): higher actions are better."""

    def forward(self, *inputs: torch.Tensor) -> torch.Tensor:
        if len(inputs) == 1:
            return torch.zeros(*inputs[0].shape[:-1], 1)
        return inputs[1].sum(-1, keepdim=True)


def _fake_critics() -> dict:
    return {
        "qvalue_network": TensorDictModule(
            _LinearCritic(), in_keys=["observation", "action"], out_keys=["state_action_value"]
        ),
        "value_network": TensorDictModule(
            _LinearCritic(), in_keys=["observation"], out_keys=["state_value"]
        ),
    }


def _train(loss_fn: WeightedMAPActorLoss, data: TensorDict, steps: int, lr: float) -> list[float]:
    optimizer = torch.optim.Adam(loss_fn.parameters(), lr=lr)
    history = []
    for _ in range(steps):
        loss = loss_fn(data.clone(False))["loss_actor"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(float(loss.detach()))
    return history


# ----------------------------------------------------------------------------- gradients
@pytest.mark.parametrize("weighting", ["advantage", "sac"])
def test_gradients_reach_only_the_actor_and_critics_stay_unchanged(weighting):
    iql = _mock_iql()
    actor = _mock_actor()
    loss_fn = WeightedMAPActorLoss.from_iql(actor, iql, weighting=weighting, action_spec=BOX)
    critic_before = {n: p.detach().clone() for n, p in iql.named_parameters()}
    critic_before.update(
        {f"target.{k}": v.clone() for k, v in iql.target_qvalue_network_params.items(True, True)}
    )
    # One optimizer over actor *and* critics: only the actor may move.
    optimizer = torch.optim.Adam([*loss_fn.parameters(), *iql.parameters()], lr=0.1)
    loss_fn(_mock_batch())["loss_actor"].backward()

    assert all(p.grad is None for p in iql.parameters())
    assert all(p.grad is None for p in iql.target_qvalue_network_params.values(True, True))
    for name, param in loss_fn.named_parameters():
        assert param.grad is not None and param.grad.abs().sum() > 0, name
    actor_before = {n: p.detach().clone() for n, p in actor.named_parameters()}
    optimizer.step()
    for name, param in iql.named_parameters():
        assert torch.equal(param, critic_before[name]), f"critic {name} moved"
    for key, value in iql.target_qvalue_network_params.items(True, True):
        assert torch.equal(value, critic_before[f"target.{key}"])
    assert any(not torch.equal(p, actor_before[n]) for n, p in actor.named_parameters())
    # The loss's parameters are the actor's own: training the loss trains the module.
    assert {id(p) for p in loss_fn.parameters()} == {id(p) for p in actor.parameters()}


def test_sac_gradient_flows_to_the_actor_through_q_of_the_sampled_action():
    iql = _mock_iql()
    actor = _mock_actor()
    # α = 0: the only path from the loss to the head is Q(s, a ~ π).
    loss_fn = WeightedMAPActorLoss.from_iql(
        actor, iql, weighting="sac", entropy_coef=0.0, action_spec=BOX
    )
    loss_fn(_mock_batch())["loss_actor"].backward()
    assert actor.head.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in iql.parameters())


# ----------------------------------------------------------------------------- weights
def test_advantage_weights_equal_clipped_exp_of_min_q_minus_v_by_hand():
    iql = _mock_iql()
    batch = _mock_batch(32)
    temperature = 2.5
    sa = torch.cat([batch["observation"], batch["action"]], -1)
    target = iql.target_qvalue_network_params
    with torch.no_grad():
        q = torch.stack([mlp_by_hand(target[k], sa) for k in range(2)]).min(0).values
        v = mlp_by_hand(iql.value_network_params, batch["observation"])
    unclipped = torch.exp(temperature * (q - v))
    max_weight = float(unclipped.median())  # so that the clip is exercised
    expected = unclipped.clamp_max(max_weight)
    loss_fn = WeightedMAPActorLoss.from_iql(
        _mock_actor(), iql, temperature=temperature, max_weight=max_weight
    )

    weights = loss_fn.advantage_weights(batch)
    assert weights.shape == (32,)
    torch.testing.assert_close(weights, expected)
    torch.testing.assert_close(loss_fn.q_value(batch), q)

    # The loss writes exactly these weights and uses them in -w·log π.
    out = WeightedMAPActorLoss.from_iql(
        _mock_actor(), iql, temperature=temperature, max_weight=max_weight, reduction="none"
    )(batch)
    actor = _mock_actor()
    dist = torch.distributions.Normal(actor(batch["observation"]), actor.std)
    log_prob = dist.log_prob(batch["action"]).sum(-1)
    torch.testing.assert_close(batch["actor_weight"], expected)
    torch.testing.assert_close(out["loss_actor"], -expected * log_prob)


def test_reduction_none_keeps_batch_shape_and_mean_and_sum_reduce_it():
    batch = _mock_batch(10)
    losses = {
        r: WeightedMAPActorLoss(_mock_actor(), weighting="uniform", reduction=r)(batch.clone())
        for r in ("none", "mean", "sum")
    }
    assert losses["none"]["loss_actor"].shape == (10,)
    assert losses["mean"]["loss_actor"].shape == ()
    torch.testing.assert_close(losses["mean"]["loss_actor"], losses["none"]["loss_actor"].mean())
    torch.testing.assert_close(losses["sum"]["loss_actor"], losses["none"]["loss_actor"].sum())
    loss_fn = WeightedMAPActorLoss(_mock_actor(), weighting="uniform")
    assert set(loss_fn.out_keys) == set(losses["mean"].keys())


# ----------------------------------------------------------------------------- training
def _toy_regression(obs_dim: int, action_dim: int, noise: float, n: int = 1024) -> TensorDict:
    gen = torch.Generator().manual_seed(1)
    observation = torch.rand(n, obs_dim, generator=gen) * 2 - 1
    mean = 0.5 * observation[:, :action_dim] - 0.3 * observation[:, -1:]
    action = mean + noise * torch.randn(n, action_dim, generator=gen)
    return TensorDict({"observation": observation, "action": action}, [n])


@pytest.mark.parametrize("actor_kind", ["planner", "linear_head"])
def test_uniform_loss_decreases_and_sigma_approaches_the_action_noise(actor_kind, make_model):
    noise = 0.2
    data = _toy_regression(OBS, ACT, noise)
    if actor_kind == "planner":
        model = make_model(num_steps=1, fit=False)
        model.normalizer.fit(data["observation"], data["action"])
        actor = PlannerActor(model, init_std=0.6)
    else:
        actor = _mock_actor()
        actor.log_std.data.fill_(math.log(0.6))
    history = _train(WeightedMAPActorLoss(actor, weighting="uniform"), data, steps=300, lr=1e-2)
    assert history[-1] < history[0] - 0.5
    assert sum(history[-10:]) / 10 < sum(history[:10]) / 10
    std = actor.std.detach()
    assert torch.all((std > 0.8 * noise) & (std < 1.25 * noise)), std


def test_higher_weighted_action_pulls_the_mean_only_under_advantage_weights():
    # One state, action -1 (A = -1, weight e^-β) and +1 (A = +1, weight e^β), equally often.
    n = 32
    data = TensorDict(
        {
            "observation": torch.zeros(2 * n, 1),
            "action": torch.cat([-torch.ones(n, 1), torch.ones(n, 1)]),
        },
        [2 * n],
    )
    state = torch.zeros(1, 1)
    means = {}
    for weighting in ("advantage", "uniform"):
        actor = _mock_actor(1, 1)
        critics = _fake_critics() if weighting == "advantage" else {}
        loss_fn = WeightedMAPActorLoss(actor, weighting=weighting, temperature=3.0, **critics)
        _train(loss_fn, data, steps=250, lr=3e-2)
        means[weighting] = float(actor(state).detach())
    assert means["advantage"] == pytest.approx(math.tanh(3.0), abs=0.05)  # weighted mean
    assert means["uniform"] == pytest.approx(0.0, abs=0.05)


# ----------------------------------------------------------------------------- keys
def test_set_keys_reads_observation_and_action_from_renamed_keys_and_writes_weight_there():
    batch = _mock_batch()
    reference = WeightedMAPActorLoss(_mock_actor(), weighting="uniform")(batch.clone())
    loss_fn = WeightedMAPActorLoss(_mock_actor(), weighting="uniform")
    loss_fn.set_keys(observation=("agent", "state"), action="act", weight="w")
    renamed = TensorDict(
        {("agent", "state"): batch["observation"], "act": batch["action"]}, batch.batch_size
    )
    out = loss_fn(renamed)
    torch.testing.assert_close(out["loss_actor"], reference["loss_actor"])
    assert "w" in renamed.keys() and "actor_weight" not in renamed.keys()
    assert loss_fn.in_keys == [("agent", "state"), "act"]
    with pytest.raises(KeyError, match="observation entry"):
        loss_fn(batch.clone())


def test_set_keys_rejects_unknown_names():
    loss_fn = WeightedMAPActorLoss(_mock_actor(), weighting="uniform")
    with pytest.raises(ValueError, match="observaton"):
        loss_fn.set_keys(observaton="obs")


def test_from_iql_uses_the_iql_value_keys():
    iql = _mock_iql()
    iql.set_keys(value="v_out")
    loss_fn = WeightedMAPActorLoss.from_iql(_mock_actor(), iql)
    assert loss_fn.tensor_keys.value == "v_out"
    assert loss_fn.tensor_keys.state_action_value == iql.tensor_keys.state_action_value


def test_input_is_unchanged_except_the_documented_weight_key(td_steady):
    batch = _mock_batch()
    batch.set(("extra", "info"), torch.arange(16))
    before = batch.clone()
    WeightedMAPActorLoss.from_iql(_mock_actor(), _mock_iql())(batch)
    assert batch["actor_weight"].shape == (16,)
    td_steady(before, batch.exclude("actor_weight"))


# ----------------------------------------------------------------------------- errors
def test_unknown_weighting_lists_the_options():
    with pytest.raises(ValueError, match="choose one of") as info:
        WeightedMAPActorLoss(_mock_actor(), weighting="awr")
    assert all(name in str(info.value) for name in WEIGHTINGS)


def test_missing_critics_are_rejected_for_weightings_that_need_them():
    critics = _fake_critics()
    with pytest.raises(ValueError, match="value_network"):
        WeightedMAPActorLoss(_mock_actor(), qvalue_network=critics["qvalue_network"])
    with pytest.raises(ValueError, match="qvalue_network"):
        WeightedMAPActorLoss(_mock_actor(), weighting="sac")
    with pytest.raises(ValueError, match="pass action_spec=env.action_spec"):
        WeightedMAPActorLoss(
            _mock_actor(), qvalue_network=critics["qvalue_network"], weighting="sac"
        )


@pytest.mark.parametrize("role", ["observation", "action"])
def test_nan_input_is_rejected_with_the_count(role):
    batch = _mock_batch()
    batch[role][:3, 0] = float("nan")
    batch[role][5, -1] = float("inf")
    with pytest.raises(ValueError, match=f"{role} holds 4 NaN/inf"):
        WeightedMAPActorLoss(_mock_actor(), weighting="uniform")(batch)


def test_wrong_action_dim_is_rejected_with_the_shape():
    batch = _mock_batch(action_dim=ACT + 1)
    with pytest.raises(ValueError, match=r"action must end with dim 2, got shape \(16, 3\)"):
        WeightedMAPActorLoss(_mock_actor(), weighting="uniform")(batch)


def test_sac_without_explicit_critic_params_keeps_gradients_out_of_q():
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    loss_fn = WeightedMAPActorLoss(
        _mock_actor(), qvalue_network=qvalue, weighting="sac", action_spec=BOX
    )
    loss_fn(_mock_batch())["loss_actor"].backward()
    assert all(p.grad is None for p in qvalue.parameters())


def test_a_ten_member_ensemble_gives_the_min_by_hand_and_its_action_gradient():
    """SO2's critic: all members evaluated in one vmapped call; the value is the min of
    the members computed one by one, and so is its gradient with respect to the action
    (the path the ``sac`` weighting trains the actor through)."""
    members = 10
    nets = []
    for seed in range(members):
        torch.manual_seed(seed)
        nets.append(
            ValueOperator(
                MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
                in_keys=["observation", "action"],
            )
        )
    params = TensorDict.from_modules(*nets, as_module=True)
    loss_fn = WeightedMAPActorLoss(
        _mock_actor(),
        qvalue_network=nets[0],
        qvalue_params=params,
        weighting="sac",
        action_spec=BOX,
    )
    batch = _mock_batch(32)
    action = batch["action"].clone().requires_grad_(True)
    batch["action"] = action
    q = loss_fn.q_value(batch)
    (grad,) = torch.autograd.grad(q.sum(), action)

    by_hand_action = action.detach().clone().requires_grad_(True)
    sa = torch.cat([batch["observation"], by_hand_action], -1)
    expected = torch.stack([mlp_by_hand(params[k].data, sa) for k in range(members)]).min(0)
    (expected_grad,) = torch.autograd.grad(expected.values.sum(), by_hand_action)
    assert expected.indices.unique().numel() > 1  # the min switches member across the batch
    torch.testing.assert_close(q, expected.values)
    torch.testing.assert_close(grad, expected_grad)
    assert all(p.grad is None for p in params.values(True, True))  # the critic stays fixed


# ----------------------------------------------------------------------------- action box
class _SlopeQ(nn.Module):
    """``Q(s, a) = slope · Σ a``: rises without end along every action dimension, as a
    critic's extrapolation outside the box may."""

    def __init__(self, slope: float) -> None:
        super().__init__()
        self.slope = slope

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return self.slope * action.sum(-1, keepdim=True)


def _sac_on_slope(
    action_spec, bias: float, slope: float = 5.0, entropy_coef: float = 0.0
) -> tuple[WeightedMAPActorLoss, LinearHeadActor]:
    actor = _mock_actor()
    with torch.no_grad():
        actor.head.weight.zero_()
        actor.head.bias.fill_(bias)  # μ(s) = bias in every state and dimension
    qvalue = ValueOperator(_SlopeQ(slope), in_keys=["observation", "action"])
    loss = WeightedMAPActorLoss(
        actor,
        qvalue_network=qvalue,
        weighting="sac",
        entropy_coef=entropy_coef,
        action_spec=action_spec,
    )
    return loss, actor


def test_sac_reads_q_at_the_clamped_action_so_an_actor_outside_the_box_gets_no_push():
    """The runaway ``algo=dual critic=so2`` had (its actor's mean at |μ| ≈ 3 and growing, a
    constant -6.0 score): Q queried outside the box rewards leaving it. With the box,
    the loss is ``-Q(s, clamp(a))``, exactly, and a mean beyond the box gets no
    gradient from Q; inside it, the same push as without a box."""
    batch = _mock_batch(4096)
    torch.manual_seed(0)
    near_edge, actor = _sac_on_slope(BOX, bias=0.8)  # N(0.8, 0.3²): a quarter of the draws clamped
    out = near_edge(batch.clone(False))
    out["loss_actor"].backward()
    # by hand, per dimension, X ~ N(μ, σ²), z = (1 - μ) / σ (the lower face is 6σ away):
    # E[clamp(X, -1, 1)] = μ Φ(z) - σ φ(z) + (1 - Φ(z)), d/dμ = Φ(z) = P(X < 1)
    mu, std = 0.8, float(actor.std.detach()[0])
    z = (1.0 - mu) / std
    cdf, pdf = 0.5 * (1 + math.erf(z / math.sqrt(2))), math.exp(-z * z / 2) / math.sqrt(2 * math.pi)
    mean_clamped = mu * cdf - std * pdf + (1 - cdf)
    # Monte-Carlo tolerances ≈ 4 standard errors (4096 draws); without the box the loss
    # would be -8.0 and the gradient -5.0
    torch.testing.assert_close(
        out["loss_actor"], torch.tensor(-5.0 * ACT * mean_clamped), atol=0.1, rtol=0
    )
    torch.testing.assert_close(
        actor.head.bias.grad, torch.full((ACT,), -5.0 * cdf), atol=0.15, rtol=0
    )

    outside, actor = _sac_on_slope(BOX, bias=4.0)  # every draw of N(4, 0.3²) is clamped to 1
    out = outside(batch.clone(False))
    torch.testing.assert_close(out["loss_actor"], torch.tensor(-5.0 * ACT))
    out["loss_actor"].backward()
    assert actor.head.bias.grad.abs().max() == 0 and actor.head.weight.grad.abs().max() == 0

    unbounded, actor = _sac_on_slope(Unbounded(shape=(ACT,)), bias=4.0)  # opt-in: no box
    unbounded(batch.clone(False))["loss_actor"].backward()
    torch.testing.assert_close(actor.head.bias.grad, torch.full((ACT,), -5.0))


def test_sac_entropy_term_scores_the_clamped_draw_and_pulls_a_mean_back_into_the_box():
    """``α·log π`` of the executed (censored) Gaussian: on a flat critic, a mean past the
    face at 1 gets ``d/dμ E[α log π] = α φ(w) / σ`` per dimension, ``w = (μ - 1) / σ``
    (only the draws on the face depend on μ, through ``log P(X ≥ 1) = log Φ(w)``), so a
    gradient step moves it back in; the Gaussian score of the raw draw gives it 0."""
    alpha, mu = 0.2, 1.2
    loss, actor = _sac_on_slope(BOX, bias=mu, slope=0.0, entropy_coef=alpha)
    torch.manual_seed(0)
    loss(_mock_batch(4096))["loss_actor"].backward()
    std = float(actor.std.detach()[0])
    w = (mu - 1.0) / std
    expected = alpha * math.exp(-w * w / 2) / math.sqrt(2 * math.pi) / std
    torch.testing.assert_close(
        actor.head.bias.grad, torch.full((ACT,), expected), atol=0.02, rtol=0
    )
    assert expected > 0.2  # inward, and far outside the tolerance


def test_the_action_box_follows_the_loss_to_its_device_and_dtype():
    loss, _ = _sac_on_slope(BOX, bias=0.0)
    loss.double()  # as .to(device): the bounds are a submodule's buffers
    assert loss.action_box.low.dtype == loss.action_box.high.dtype == torch.float64
