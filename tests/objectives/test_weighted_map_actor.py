"""Tests for the weighted MAP actor loss of DUAL (Eq. 7)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from toy import linear_head_actor, mlp_by_hand, observation_action_batch, tiny_iql_loss

from torchrl_dual.modules import PlannerActor
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS, WeightedMAPActorLoss

OBS, ACT = 3, 2
BOX = Bounded(-1.0, 1.0, shape=(ACT,))


# ----------------------------------------------------------------------------- fake critics
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
    iql = tiny_iql_loss()
    actor = linear_head_actor()
    loss_fn = WeightedMAPActorLoss.from_iql(actor, iql, weighting=weighting, action_spec=BOX)
    critic_before = {n: p.detach().clone() for n, p in iql.named_parameters()}
    critic_before.update(
        {f"target.{k}": v.clone() for k, v in iql.target_qvalue_network_params.items(True, True)}
    )
    # One optimizer over actor *and* critics: only the actor may move.
    optimizer = torch.optim.Adam([*loss_fn.parameters(), *iql.parameters()], lr=0.1)
    loss_fn(observation_action_batch())["loss_actor"].backward()

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


# ----------------------------------------------------------------------------- weights
def test_advantage_weights_equal_clipped_exp_of_min_q_minus_v_by_hand():
    iql = tiny_iql_loss()
    batch = observation_action_batch(32)
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
        linear_head_actor(), iql, temperature=temperature, max_weight=max_weight
    )

    weights = loss_fn.advantage_weights(batch)
    assert weights.shape == (32,)
    torch.testing.assert_close(weights, expected)
    torch.testing.assert_close(loss_fn.q_value(batch), q)

    # The loss writes exactly these weights and uses them in -w·log π.
    out = WeightedMAPActorLoss.from_iql(
        linear_head_actor(), iql, temperature=temperature, max_weight=max_weight, reduction="none"
    )(batch)
    actor = linear_head_actor()
    dist = torch.distributions.Normal(actor(batch["observation"]), actor.std)
    log_prob = dist.log_prob(batch["action"]).sum(-1)
    torch.testing.assert_close(batch["actor_weight"], expected)
    torch.testing.assert_close(out["loss_actor"], -expected * log_prob)


def test_reduction_none_keeps_batch_shape_and_mean_and_sum_reduce_it():
    batch = observation_action_batch(10)
    losses = {
        r: WeightedMAPActorLoss(linear_head_actor(), weighting="uniform", reduction=r)(
            batch.clone()
        )
        for r in ("none", "mean", "sum")
    }
    assert losses["none"]["loss_actor"].shape == (10,)
    assert losses["mean"]["loss_actor"].shape == ()
    torch.testing.assert_close(losses["mean"]["loss_actor"], losses["none"]["loss_actor"].mean())
    torch.testing.assert_close(losses["sum"]["loss_actor"], losses["none"]["loss_actor"].sum())
    loss_fn = WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")
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
        actor = linear_head_actor()
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
        actor = linear_head_actor(1, 1)
        critics = _fake_critics() if weighting == "advantage" else {}
        loss_fn = WeightedMAPActorLoss(actor, weighting=weighting, temperature=3.0, **critics)
        _train(loss_fn, data, steps=250, lr=3e-2)
        means[weighting] = float(actor(state).detach())
    assert means["advantage"] == pytest.approx(math.tanh(3.0), abs=0.05)  # weighted mean
    assert means["uniform"] == pytest.approx(0.0, abs=0.05)


# ----------------------------------------------------------------------------- keys
def test_set_keys_reads_observation_and_action_from_renamed_keys_and_writes_weight_there():
    batch = observation_action_batch()
    reference = WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")(batch.clone())
    loss_fn = WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")
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
    loss_fn = WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")
    with pytest.raises(ValueError, match="observaton"):
        loss_fn.set_keys(observaton="obs")


def test_from_iql_uses_the_iql_value_keys():
    iql = tiny_iql_loss()
    iql.set_keys(value="v_out")
    loss_fn = WeightedMAPActorLoss.from_iql(linear_head_actor(), iql)
    assert loss_fn.tensor_keys.value == "v_out"
    assert loss_fn.tensor_keys.state_action_value == iql.tensor_keys.state_action_value


def test_input_is_unchanged_except_the_documented_weight_key(td_steady):
    batch = observation_action_batch()
    batch.set(("extra", "info"), torch.arange(16))
    before = batch.clone()
    WeightedMAPActorLoss.from_iql(linear_head_actor(), tiny_iql_loss())(batch)
    assert batch["actor_weight"].shape == (16,)
    td_steady(before, batch.exclude("actor_weight"))


# ----------------------------------------------------------------------------- errors
def test_unknown_weighting_lists_the_options():
    with pytest.raises(ValueError, match="choose one of") as info:
        WeightedMAPActorLoss(linear_head_actor(), weighting="awr")
    assert all(name in str(info.value) for name in WEIGHTINGS)


def test_missing_critics_are_rejected_for_weightings_that_need_them():
    critics = _fake_critics()
    with pytest.raises(ValueError, match="value_network"):
        WeightedMAPActorLoss(linear_head_actor(), qvalue_network=critics["qvalue_network"])
    with pytest.raises(ValueError, match="qvalue_network"):
        WeightedMAPActorLoss(linear_head_actor(), weighting="sac")
    with pytest.raises(ValueError, match="pass action_spec=env.action_spec"):
        WeightedMAPActorLoss(
            linear_head_actor(), qvalue_network=critics["qvalue_network"], weighting="sac"
        )


@pytest.mark.parametrize("role", ["observation", "action"])
def test_nan_input_is_rejected_with_the_count(role):
    batch = observation_action_batch()
    batch[role][:3, 0] = float("nan")
    batch[role][5, -1] = float("inf")
    with pytest.raises(ValueError, match=f"{role} holds 4 NaN/inf"):
        WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")(batch)


def test_wrong_action_dim_is_rejected_with_the_shape():
    batch = observation_action_batch(action_dim=ACT + 1)
    with pytest.raises(ValueError, match=r"action must end with dim 2, got shape \(16, 3\)"):
        WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")(batch)
