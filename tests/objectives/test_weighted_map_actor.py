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


# ----------------------------------------------------------------------------- defaults
def test_documented_defaults_advantage_beta_3_w_max_100_alpha_0_2_mean():
    """The docstring's defaults, and the default advantage weights by hand:
    ``min(exp(3·(Q − V)), 100)`` with ``Q = Σ a`` and ``V = 0`` (an action summing to
    2 gives ``e^6 ≈ 403``: clipped to 100)."""
    loss_fn = WeightedMAPActorLoss(linear_head_actor(), **_fake_critics())
    assert loss_fn.weighting == "advantage"
    assert (loss_fn.temperature, loss_fn.max_weight, loss_fn.entropy_coef) == (3.0, 100.0, 0.2)
    assert loss_fn.reduction == "mean"
    action = torch.tensor([[-0.5, 0.2], [0.5, 0.5], [1.0, 1.0], [0.0, 0.0]])
    batch = TensorDict({"observation": torch.zeros(4, OBS), "action": action}, [4])
    expected = torch.tensor([math.exp(-0.9), math.exp(3.0), 100.0, 1.0])
    torch.testing.assert_close(loss_fn.advantage_weights(batch), expected)


# ----------------------------------------------------------------------------- errors (text)
def test_missing_value_network_error_says_it_is_iql_s_v():
    critics = _fake_critics()
    with pytest.raises(
        ValueError, match=r"^weighting='advantage' needs a value_network \(V\(s\) of IQL\)\.$"
    ):
        WeightedMAPActorLoss(linear_head_actor(), qvalue_network=critics["qvalue_network"])


def test_missing_action_spec_error_for_sac_explains_the_clamp_and_the_unbounded_opt_in():
    critics = _fake_critics()
    with pytest.raises(ValueError) as info:
        WeightedMAPActorLoss(
            linear_head_actor(), qvalue_network=critics["qvalue_network"], weighting="sac"
        )
    assert str(info.value) == (
        "weighting='sac' reads Q at samples of the unbounded Gaussian N(mu, sigma^2): "
        "pass action_spec=env.action_spec so they are clamped to the executed action "
        "(torchrl.data.Unbounded(...) for an action space without bounds)."
    )


@pytest.mark.parametrize("role", ["observation", "action"])
def test_nan_input_error_tells_to_clean_the_batch(role):
    batch = observation_action_batch()
    batch[role][2, 0] = float("nan")
    with pytest.raises(
        ValueError, match=rf"^{role} holds 1 NaN/inf entries; clean the batch first\.$"
    ):
        WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")(batch)


# ----------------------------------------------------------------------------- batch shapes
def _gaussian_log_prob_by_hand(action, loc, std):
    """``Σ_j log N(a_j; μ_j, σ_j²)`` written out."""
    z = (action - loc) / std
    return (-0.5 * z**2 - torch.log(std) - 0.5 * math.log(2 * math.pi)).sum(-1)


def test_a_two_dimensional_batch_gives_per_sample_losses_weights_and_q_by_hand():
    """A ``[4, 3]`` batch (e.g. a batch of sub-trajectories): ``Q``, the weights and
    ``−w·log π`` keep the ``[4, 3]`` batch shape, the log-likelihood sums over the
    action dimension only."""
    gen = torch.Generator().manual_seed(3)
    observation = torch.randn(4, 3, OBS, generator=gen)
    action = torch.rand(4, 3, ACT, generator=gen) * 2 - 1
    batch = TensorDict({"observation": observation, "action": action}, [4, 3])
    actor = linear_head_actor()
    loss_fn = WeightedMAPActorLoss(
        actor, temperature=0.7, max_weight=1.5, reduction="none", **_fake_critics()
    )
    q = action.sum(-1)
    weight = torch.exp(0.7 * q).clamp_max(1.5)
    with torch.no_grad():
        log_prob = _gaussian_log_prob_by_hand(action, actor(observation), actor.std)
    torch.testing.assert_close(loss_fn.q_value(batch), q)
    out = loss_fn(batch)
    assert out["loss_actor"].shape == (4, 3)
    torch.testing.assert_close(out["loss_actor"].detach(), -weight * log_prob)
    torch.testing.assert_close(batch["actor_weight"], weight)
    torch.testing.assert_close(out["log_prob"], log_prob.mean())
    torch.testing.assert_close(out["weight_mean"], weight.mean())


def test_torchrl_s_collector_mask_drops_padded_samples_from_the_mean():
    """``("collector", "mask")`` (TorchRL's padding mask) is honoured by the mean: the
    loss is the average of ``−log π`` over the valid samples only."""
    batch = observation_action_batch(6)
    valid = torch.tensor([True, False, True, True, False, True])
    batch.set(("collector", "mask"), valid)
    actor = linear_head_actor()
    with torch.no_grad():
        log_prob = _gaussian_log_prob_by_hand(
            batch["action"], actor(batch["observation"]), actor.std
        )
    out = WeightedMAPActorLoss(actor, weighting="uniform")(batch)
    torch.testing.assert_close(out["loss_actor"].detach(), -log_prob[valid].mean())


# ----------------------------------------------------------------------------- critic reads
class _OptionalBonusCritic(nn.Module):
    """``Q(s, a) = Σ a (+ bonus)``: its third input is optional (``None`` when absent)."""

    def forward(self, observation, action, bonus=None):
        q = action.sum(-1, keepdim=True)
        return q if bonus is None else q + bonus


def test_a_critic_input_missing_from_the_batch_reaches_it_as_none():
    """The critic is fed the batch entries it names that exist; an optional input the
    batch lacks is left to the module (``TensorDictModule`` passes ``None``), in the
    advantage weights and in the ``sac`` loss alike."""
    qvalue = TensorDictModule(
        _OptionalBonusCritic(),
        in_keys=["observation", "action", "bonus"],
        out_keys=["state_action_value"],
    )
    batch = observation_action_batch(5)
    critics = _fake_critics()
    advantage = WeightedMAPActorLoss(
        linear_head_actor(),
        qvalue_network=qvalue,
        value_network=critics["value_network"],
        temperature=1.0,
    )
    torch.testing.assert_close(advantage.q_value(batch), batch["action"].sum(-1))
    torch.testing.assert_close(
        advantage.advantage_weights(batch), torch.exp(batch["action"].sum(-1))
    )
    sac = WeightedMAPActorLoss(
        linear_head_actor(),
        qvalue_network=qvalue,
        weighting="sac",
        entropy_coef=0.0,
        action_spec=BOX,
    )
    torch.manual_seed(0)
    loss = sac(batch.clone(False))["loss_actor"]
    assert -2.0 <= float(loss.detach()) <= 2.0  # minus a sum of two clamped actions
    batch.set("bonus", torch.full((5, 1), 10.0))
    torch.testing.assert_close(advantage.q_value(batch), batch["action"].sum(-1) + 10.0)


def test_critic_weights_are_read_detached_and_without_deprecated_calls():
    """``Q`` of a batch that carries no gradient carries none either: the critic's own
    weights enter detached (no graph is built through them), and reading them raises
    no (deprecation) warning."""
    import warnings

    from torchrl.modules import MLP, ValueOperator

    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    value = ValueOperator(
        MLP(in_features=OBS, out_features=1, num_cells=[8]), in_keys=["observation"]
    )
    loss_fn = WeightedMAPActorLoss(linear_head_actor(), qvalue_network=qvalue, value_network=value)
    batch = observation_action_batch()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        q = loss_fn.q_value(batch)
        weights = loss_fn.advantage_weights(batch)
    assert not q.requires_grad and q.grad_fn is None
    assert weights.shape == (16,) and torch.isfinite(weights).all()
    assert all(p.requires_grad and type(p) is nn.Parameter for p in qvalue.parameters())


# ----------------------------------------------------------------------------- value params
def _linear_value(weight: list[float], bias: float) -> tuple[TensorDictModule, TensorDict]:
    """A ``V(s) = w·s + b`` network whose own weights are zero, and separate parameters
    ``(w, b)`` for it (as a critic loss holds them)."""
    linear = nn.Linear(OBS, 1)
    nn.init.zeros_(linear.weight)
    nn.init.zeros_(linear.bias)
    network = TensorDictModule(linear, in_keys=["observation"], out_keys=["state_value"])
    params = TensorDict.from_module(network).clone()
    params["module", "weight"] = torch.tensor([weight])
    params["module", "bias"] = torch.tensor([bias])
    return network, params


def test_value_params_are_the_weights_v_is_read_with():
    """``value_params`` replace the value network's own weights: with ``Q = Σ a`` and
    ``V(s) = w·s + b`` the weight is ``exp(β·(Σ a − w·s − b))`` (the module's own
    weights, all zero, would give ``exp(β·Σ a)``)."""
    network, params = _linear_value([0.5, -1.0, 0.25], 0.3)
    batch = observation_action_batch(8)
    loss_fn = WeightedMAPActorLoss(
        linear_head_actor(),
        qvalue_network=_fake_critics()["qvalue_network"],
        value_network=network,
        value_params=params,
        temperature=0.5,
        max_weight=1e6,
    )
    v = batch["observation"] @ torch.tensor([0.5, -1.0, 0.25]) + 0.3
    expected = torch.exp(0.5 * (batch["action"].sum(-1) - v))
    torch.testing.assert_close(loss_fn.advantage_weights(batch), expected)


def test_from_iql_reads_v_with_the_critic_loss_s_value_network_params():
    """``from_iql`` takes V's weights from the critic loss's ``value_network_params``
    (the parameters an IQL-style loss trains), not from the module it wraps."""
    from types import SimpleNamespace

    network, params = _linear_value([-0.5, 0.0, 1.0], -0.2)
    critic_loss = SimpleNamespace(
        qvalue_network=_fake_critics()["qvalue_network"],
        target_qvalue_network_params=None,
        value_network=network,
        value_network_params=params,
        tensor_keys=SimpleNamespace(state_action_value="state_action_value", value="state_value"),
    )
    loss_fn = WeightedMAPActorLoss.from_iql(
        linear_head_actor(), critic_loss, temperature=1.0, max_weight=1e6
    )
    batch = observation_action_batch(8)
    v = batch["observation"] @ torch.tensor([-0.5, 0.0, 1.0]) - 0.2
    expected = torch.exp(batch["action"].sum(-1) - v)
    torch.testing.assert_close(loss_fn.advantage_weights(batch), expected)


def test_a_dropout_critic_ensemble_is_read_in_training_mode_and_its_eval_min_by_hand():
    """TorchRL's rule: a critic holding dropout gets ``vmap_randomness = "different"``,
    and the vmapped twin-Q read runs in training mode (the default ``"error"`` mode
    would refuse the random op); in eval mode it is the min of the members by hand."""
    from torchrl.modules import MLP, ValueOperator

    torch.manual_seed(0)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8], dropout=0.5),
        in_keys=["observation", "action"],
    )
    members = [TensorDict.from_module(qvalue).clone()]
    members.append(members[0].apply(lambda x: 0.5 * x))
    params = torch.stack(members)
    loss_fn = WeightedMAPActorLoss(
        linear_head_actor(), qvalue_network=qvalue, qvalue_params=params, weighting="uniform"
    )
    assert loss_fn.vmap_randomness == "different"
    batch = observation_action_batch(32)
    q = loss_fn.q_value(batch)
    assert q.shape == (32,) and torch.isfinite(q).all()
    qvalue.eval()
    expected = []
    for member in members:
        with member.to_module(qvalue):
            expected.append(qvalue(batch.clone())["state_action_value"].squeeze(-1))
    torch.testing.assert_close(loss_fn.q_value(batch), torch.stack(expected).min(0).values)


def test_a_torchrl_probabilistic_actor_is_refused_at_construction_with_the_fix():
    from torchrl.modules import MLP, ProbabilisticActor

    actor = ProbabilisticActor(
        TensorDictModule(MLP(in_features=3, out_features=4), ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=torch.distributions.Normal,
    )
    with pytest.raises(TypeError, match="LastLayerActor.*ProbabilisticActor.*from_actor"):
        WeightedMAPActorLoss(actor, weighting="uniform")


def test_a_batch_in_another_dtype_names_both_dtypes():
    batch = observation_action_batch().apply(lambda t: t.double())
    with pytest.raises(TypeError, match="torch.float64.*torch.float32"):
        WeightedMAPActorLoss(linear_head_actor(), weighting="uniform")(batch)
    out = WeightedMAPActorLoss(linear_head_actor(), weighting="uniform").double()(batch)
    assert out["loss_actor"].dtype == torch.float64


def test_non_finite_advantage_weights_are_refused_with_where_they_come_from():
    """A NaN observation is named with its index; a critic whose weights diverged is said
    to have diverged. ``check_finite=False`` turns the check off."""
    iql = tiny_iql_loss()
    batch = observation_action_batch()
    loss_fn = WeightedMAPActorLoss.from_iql(linear_head_actor(), iql)
    bad = batch.clone()
    bad["observation"][3, 0] = float("nan")
    with pytest.raises(
        ValueError, match=r"advantage weights holds a NaN or inf.*'observation'.*index 3"
    ):
        loss_fn.advantage_weights(bad)
    with torch.no_grad():
        iql.value_network_params.apply_(lambda p: p.fill_(float("nan")))
    with pytest.raises(ValueError, match="the weights diverged"):
        loss_fn(batch)
    loss_fn.check_finite = False
    assert torch.isnan(loss_fn(batch)["loss_actor"])
