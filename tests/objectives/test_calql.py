"""Tests for the Cal-QL critic loss (torchrl_dual/objectives/calql.py)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import CQLLoss
from toy import mlp_by_hand, tanh_normal_actor

from torchrl_dual.objectives import PENALTY_LAYOUTS, CalQLLoss

OBS, ACT, BATCH, NUM = 3, 2, 6, 4


# ----------------------------------------------------------------------------- factories
def _mock_nets(seed: int = 0) -> tuple[ProbabilisticActor, ValueOperator]:
    torch.manual_seed(seed)
    actor = tanh_normal_actor(OBS, ACT, Bounded(-torch.ones(ACT), torch.ones(ACT), (ACT,)))
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    return actor, qvalue


def _mock_loss(cls=CalQLLoss, seed: int = 0, **kwargs) -> CQLLoss:
    actor, qvalue = _mock_nets(seed)
    loss = cls(actor, qvalue, num_random=NUM, **kwargs)
    loss.make_value_estimator(gamma=0.9)
    return loss


def _mock_batch(mc_return: float | torch.Tensor = -math.inf, seed: int = 0) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    bound = torch.as_tensor(mc_return, dtype=torch.float32).expand(BATCH, 1).clone()
    return TensorDict(
        {
            "observation": torch.randn(BATCH, OBS, generator=gen),
            "action": torch.rand(BATCH, ACT, generator=gen) * 2 - 1,
            "mc_return": bound,
            ("next", "observation"): torch.randn(BATCH, OBS, generator=gen),
            ("next", "reward"): torch.randn(BATCH, 1, generator=gen),
            ("next", "done"): torch.zeros(BATCH, 1, dtype=torch.bool),
            ("next", "terminated"): torch.zeros(BATCH, 1, dtype=torch.bool),
        },
        [BATCH],
    )


def _penalty(loss: CQLLoss, batch: TensorDict, seed: int = 1) -> torch.Tensor:
    """``loss_cql`` of one batch, the policy draws seeded after the Bellman loss."""
    td = batch.clone()
    loss.q_loss(td)
    torch.manual_seed(seed)
    return loss.cql_loss(td)[0]


def _q_by_hand(params: TensorDict, obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """``Q(s, a)`` of the one-hidden-layer TorchRL ``MLP`` Q network, written out."""
    return mlp_by_hand(params, torch.cat([obs, action], -1))


def _spied_penalty(loss: CalQLLoss, batch: TensorDict, seed: int = 1):
    """``cql_loss`` after ``q_loss`` on a copy of ``batch`` with the policy draws spied:
    the input as ``cql_loss`` left it, its two outputs and the two draws."""
    draws = []
    original = loss._get_policy_actions

    def spy(data, params, num_actions, **kwargs):
        out = original(data, params, num_actions=num_actions, **kwargs)
        draws.append(out)
        return out

    loss._get_policy_actions = spy
    td = batch.clone()
    loss.q_loss(td)
    torch.manual_seed(seed)
    value, metadata = loss.cql_loss(td)
    del loss._get_policy_actions
    return td, value, metadata, draws


def _by_hand(loss: CalQLLoss, batch: TensorDict, bound: torch.Tensor, draws, seed: int = 1):
    """Cal-QL's penalty written out (the ``"calql"`` layout) on the flattened batch, every Q
    recomputed: the per-network, per-transition penalties ``[2, N]`` and the fraction of the
    ``2 kinds x 2 networks x NUM`` policy Q-values of each transition below its bound."""
    n = batch.numel()
    torch.manual_seed(seed)
    uniform = torch.empty(n * NUM, ACT).uniform_(-1, 1)  # CQL's first draw
    (curr, curr_log_pi), (nxt, next_log_pi) = draws
    curr_action, next_action = curr["action"].reshape(-1, ACT), nxt["action"].reshape(-1, ACT)
    curr_log_pi, next_log_pi = curr_log_pi.reshape(-1), next_log_pi.reshape(-1)
    obs = batch["observation"].reshape(n, OBS)
    obs_rep = obs.repeat_interleave(NUM, 0)
    g = bound.reshape(n).repeat_interleave(NUM)
    w, temp = loss.min_q_weight, loss.temperature
    per_net, raised = [], []
    for net in range(2):
        params = loss.qvalue_network_params[net]
        q_curr = _q_by_hand(params, obs_rep, curr_action)
        q_next = _q_by_hand(params, obs_rep, next_action)
        raised += [q_curr < g, q_next < g]
        terms = torch.stack(
            [
                _q_by_hand(params, obs_rep, uniform) - ACT * math.log(0.5),
                torch.maximum(q_curr, g) - curr_log_pi,
                torch.maximum(q_next, g) - next_log_pi,
            ],
            -1,
        ).reshape(n, 3 * NUM)  # the 3·NUM actions of each state
        pred = _q_by_hand(params, obs, batch["action"].reshape(n, ACT))
        per_net.append(w * (temp * torch.logsumexp(terms / temp, -1) - pred))
    rate = torch.stack(raised).float().reshape(4, n, NUM).mean((0, 2))
    return torch.stack(per_net), rate


def _penalty_by_hand(loss: CalQLLoss, batch: TensorDict, bound: torch.Tensor, seed: int = 1):
    """``loss_cql`` (mean reduction) and Cal-QL's penalty written out."""
    _, value, _, draws = _spied_penalty(loss, batch, seed)
    per_net, _ = _by_hand(loss, batch, bound, draws, seed)
    return value, per_net.sum(0).mean()


# ----------------------------------------------------------------------------- the penalty
@pytest.mark.parametrize("bound", [-math.inf, 0.3, "mixed"])
def test_the_penalty_equals_the_logsumexp_of_clipped_policy_q_computed_by_hand(bound):
    loss = _mock_loss(min_q_weight=3.0, temperature=2.0)
    if bound == "mixed":  # half the states bounded above their Q, half not
        bound = torch.tensor([5.0, -5.0, 0.2, -math.inf, 1.0, -1.0])
    bound = torch.as_tensor(bound).expand(BATCH).clone()
    batch = _mock_batch(bound.unsqueeze(-1))
    value, expected = _penalty_by_hand(loss, batch, bound)
    torch.testing.assert_close(value, expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("weight, temperature", [(1.0, 1.0), (3.0, 2.0)])
def test_with_the_bound_at_minus_inf_the_torchrl_layout_gives_cqllosss_outputs_exactly(
    weight, temperature
):
    kwargs = {"min_q_weight": weight, "temperature": temperature, "loss_function": "l2"}
    cal = _mock_loss(penalty_layout="torchrl", **kwargs)
    cql = _mock_loss(CQLLoss, **kwargs)
    batch = _mock_batch(-math.inf)
    torch.manual_seed(3)
    out_cal = cal(batch.clone())
    torch.manual_seed(3)
    out_cql = cql(batch.clone())
    for key in out_cql.keys():
        torch.testing.assert_close(out_cal[key], out_cql[key], rtol=1e-6, atol=1e-6)
    assert out_cal["bound_rate"] == 0


@pytest.mark.parametrize("scale", [1.0, 100.0])
def test_the_bellman_loss_is_the_references_squared_error_not_cqlloss_s_huber(scale):
    """Cal-QL's, CQL's, CORL's and d3rlpy's code regress Q by squared error; TorchRL's
    CQLLoss defaults to smooth-L1. Scaling the TD errors by k scales the squared error by
    k², the Huber loss (errors beyond 1) by about k only."""
    batch = _mock_batch(-math.inf)
    batch["next", "reward"] = batch["next", "reward"] * scale
    losses = {}
    for name, cls, kwargs in (
        ("calql", CalQLLoss, {}),
        ("l2", CQLLoss, {"loss_function": "l2"}),
        ("huber", CQLLoss, {}),
    ):
        torch.manual_seed(3)
        losses[name] = _mock_loss(cls, **kwargs).q_loss(batch.clone())[0]
    torch.testing.assert_close(losses["calql"], losses["l2"])
    assert _mock_loss().loss_function == "l2"
    if scale > 1:  # errors far beyond 1: the squared error is ≫ the Huber loss
        assert losses["calql"] > 20 * losses["huber"]


def test_a_bound_above_the_policy_q_raises_the_penalty_and_one_below_leaves_cqls():
    for layout in PENALTY_LAYOUTS:
        loss = _mock_loss(penalty_layout=layout)
        free = _penalty(loss, _mock_batch(-math.inf))
        below = _penalty(loss, _mock_batch(-100.0))
        above = _penalty(loss, _mock_batch(100.0))
        assert torch.equal(below, free), layout
        # every policy Q becomes G = 100: the logsumexp is at least 100 + log of its count.
        assert above > free + 50, layout
        td = _mock_batch(100.0)
        loss(td)
        assert torch.equal(td["bound_rate"], torch.ones(BATCH))


def test_the_bound_binds_per_state_and_reduction_none_gives_one_penalty_per_transition():
    base = _mock_batch(-math.inf)
    bound = torch.full((BATCH, 1), -math.inf)
    bound[2] = 100.0
    for layout in PENALTY_LAYOUTS:
        per_row = _mock_loss(penalty_layout=layout, reduction="none", scalar_output_mode="exclude")
        free = _penalty(per_row, base)
        one = _penalty(per_row, base.clone().set("mc_return", bound))
        assert one.shape == (BATCH,)
        assert ((one - free).abs() > 1e-6).tolist() == [i == 2 for i in range(BATCH)], layout
        mean = _penalty(_mock_loss(penalty_layout=layout), base)
        torch.testing.assert_close(free.mean(), mean)


# ----------------------------------------------------------------------------- gradients
def test_the_critic_loss_trains_the_q_networks_only():
    loss = _mock_loss()
    out = loss(_mock_batch(0.5))
    (out["loss_qvalue"] + out["loss_cql"]).backward()
    q_grads = [p.grad for p in loss.qvalue_network_params.values(True, True)]
    assert all(g is not None and g.abs().sum() > 0 for g in q_grads)
    actor_grads = [p.grad for p in loss.actor_network_params.values(True, True)]
    assert all(g is None or g.abs().sum() == 0 for g in actor_grads)
    assert all(p.grad is None for p in loss.target_qvalue_network_params.values(True, True))


def test_policy_q_values_below_the_bound_get_no_gradient():
    # With G = 100 above every policy Q, the clipped terms are constants and dominate the
    # logsumexp (the uniform terms' softmax weights underflow): the penalty's gradient is
    # that of -min_q_weight · mean Q(s, a_data), summed over the two networks.
    loss = _mock_loss(min_q_weight=2.0)
    batch = _mock_batch(100.0)
    _penalty(loss, batch).backward()
    clipped = [p.grad.clone() for p in loss.qvalue_network_params.values(True, True)]
    loss.zero_grad()
    total = sum(
        -2.0
        * _q_by_hand(loss.qvalue_network_params[net], batch["observation"], batch["action"]).mean()
        for net in range(2)
    )
    total.backward()
    by_hand = [p.grad for p in loss.qvalue_network_params.values(True, True)]
    for got, expected in zip(clipped, by_hand, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)


# ----------------------------------------------------------------------------- keys, errors
def test_set_keys_renames_the_bound_and_a_missing_bound_names_the_fix():
    loss = _mock_loss()
    batch = _mock_batch(0.0)
    with pytest.raises(KeyError, match=r"set_keys\(mc_return=\.\.\.\)"):
        loss(batch.exclude("mc_return"))
    loss.set_keys(mc_return="return_to_go")
    assert "return_to_go" in loss.in_keys and "mc_return" not in loss.in_keys
    out = loss(batch.rename_key_("mc_return", "return_to_go"))
    assert "bound_rate" in out.keys()


def test_bad_layout_and_bound_shape_are_rejected():
    with pytest.raises(
        ValueError,
        match=r"penalty_layout='cql' is not one of \('calql', 'torchrl'\): 'calql' follows the "
        r"Cal-QL reference code, 'torchrl' reproduces CQLLoss's grouping\.",
    ):
        _mock_loss(penalty_layout="cql")
    batch = _mock_batch(0.0)
    batch.set("mc_return", torch.zeros(BATCH, 2))
    with pytest.raises(ValueError, match="one return per transition"):
        _mock_loss()(batch)


def test_in_keys_list_cqlloss_s_then_the_bound_in_a_fixed_order():
    assert _mock_loss().in_keys == [*_mock_loss(cls=CQLLoss).in_keys, "mc_return"]


# ----------------------------------------------------------------------------- per-sample outputs
def test_the_per_network_penalties_bound_rate_and_metadata_match_a_hand_computation():
    """``cql_q1_loss`` / ``cql_q2_loss`` are the two networks' per-transition penalties,
    ``bound_rate`` the per-transition fraction of raised policy Q-values, and the metadata
    its mean."""
    loss = _mock_loss(min_q_weight=3.0, temperature=2.0)
    # bounds inside the Q-values' range for states 1, 2 and 4: some of their policy Qs raised
    bound = torch.tensor([5.0, -0.3, -0.3, -math.inf, -0.2, -1.0])
    batch = _mock_batch(bound.unsqueeze(-1))
    td, value, metadata, draws = _spied_penalty(loss, batch)
    per_net, rate = _by_hand(loss, batch, bound, draws)
    torch.testing.assert_close(td["cql_q1_loss"], per_net[0], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(td["cql_q2_loss"], per_net[1], rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(td["bound_rate"], rate)
    assert ((rate > 0) & (rate < 1)).any()  # a real mix, not only 0 and 1
    assert list(metadata) == ["bound_rate"]
    torch.testing.assert_close(metadata["bound_rate"], rate.mean())
    assert not metadata["bound_rate"].requires_grad


@pytest.mark.parametrize("layout", PENALTY_LAYOUTS)
def test_a_two_dimensional_batch_gives_the_hand_penalties_of_its_transitions(layout):
    """A ``[2, 3]`` batch: one penalty and one ``bound_rate`` per transition, each that of
    the hand computation on the flattened batch (``"calql"``; for ``"torchrl"`` the shape
    and the bound rate)."""
    loss = _mock_loss(penalty_layout=layout, reduction="none", scalar_output_mode="exclude")
    bound = torch.tensor([5.0, -5.0, 0.2, -math.inf, 1.0, -1.0])
    flat = _mock_batch(bound.unsqueeze(-1))
    batch = flat.reshape(2, 3)
    td, value, _, draws = _spied_penalty(loss, batch)
    per_net, rate = _by_hand(loss, flat, bound, draws)
    assert value.shape == (2, 3)
    torch.testing.assert_close(td["bound_rate"], rate.reshape(2, 3))
    if layout == "calql":
        torch.testing.assert_close(value, per_net.sum(0).reshape(2, 3), rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(
            td["cql_q1_loss"], per_net[0].reshape(2, 3), rtol=1e-5, atol=1e-5
        )


def test_a_policy_q_equal_to_the_bound_is_not_counted_as_raised():
    """With a constant critic ``Q ≡ 0.25`` every policy Q-value equals a bound of 0.25: none
    lies below it (``bound_rate`` 0); a bound of 0.5 raises all of them (1)."""
    for bound, expected in ((0.25, 0.0), (0.5, 1.0)):
        loss = _mock_loss()
        with torch.no_grad():
            loss.qvalue_network_params["module", "2", "weight"].zero_()
            loss.qvalue_network_params["module", "2", "bias"].fill_(0.25)
        td, _, metadata, _ = _spied_penalty(loss, _mock_batch(bound))
        assert torch.equal(td["bound_rate"], torch.full((BATCH,), expected)), bound
        assert float(metadata["bound_rate"]) == expected


def test_a_float64_bound_gives_the_penalty_in_the_critic_s_float32():
    loss = _mock_loss(min_q_weight=2.0)
    bound = torch.tensor([5.0, -5.0, 0.2, -math.inf, 1.0, -1.0], dtype=torch.float64)
    batch = _mock_batch(bound.float().unsqueeze(-1)).set("mc_return", bound.unsqueeze(-1))
    _, value, _, draws = _spied_penalty(loss, batch)
    per_net, _ = _by_hand(loss, batch, bound.float(), draws)
    assert value.dtype == torch.float32
    torch.testing.assert_close(value, per_net.sum(0).mean(), rtol=1e-5, atol=1e-5)


def test_the_mean_penalty_skips_transitions_masked_out_by_the_collector_mask():
    """``("collector", "mask")`` (TorchRL's padding mask) drops its ``False`` transitions
    from the mean of ``loss_cql``."""
    loss = _mock_loss()
    bound = torch.full((BATCH,), 0.3)
    mask = torch.tensor([True, True, False, True, False, True])
    batch = _mock_batch(bound.unsqueeze(-1)).set(("collector", "mask"), mask)
    _, value, _, draws = _spied_penalty(loss, batch)
    per_net, _ = _by_hand(loss, batch, bound, draws)
    torch.testing.assert_close(value, per_net.sum(0)[mask].mean(), rtol=1e-5, atol=1e-5)


def test_under_compile_cql_loss_clears_the_weakrefs_that_cqlloss_clears(monkeypatch):
    """Inside ``torch.compile`` (``is_compiling`` forced true) ``cql_loss`` releases the
    compile references of its input and of the four parameter sets, as
    ``CQLLoss.cql_loss`` does."""
    import torchrl.objectives.common as common

    def cleared_by(loss):
        td = _mock_batch(0.3)
        loss.q_loss(td)
        seen = []
        real = common.is_tensor_collection

        def spy(obj):
            seen.append(obj)
            return real(obj)

        monkeypatch.setattr(common, "is_compiling", lambda: True)
        monkeypatch.setattr(common, "is_tensor_collection", spy)
        loss.cql_loss(td)
        monkeypatch.undo()
        assert len(seen) == 5, [type(x) for x in seen]
        assert seen[0] is td
        assert seen[1] is loss.actor_network_params
        assert seen[2] is loss.qvalue_network_params
        assert (seen[3] == loss.actor_network_params.data).all()  # no target actor: its data
        assert seen[4] is loss.target_qvalue_network_params

    cleared_by(_mock_loss(CQLLoss))  # the reference
    cleared_by(_mock_loss())


def test_cql_loss_before_q_loss_names_the_fix():
    with pytest.raises(KeyError, match=r"which q_loss writes: call q_loss\(tensordict\) first"):
        _mock_loss().cql_loss(_mock_batch(0.0))


@pytest.mark.parametrize("layout", PENALTY_LAYOUTS)
def test_the_loss_compiles_whole_and_gives_the_eager_losses(layout):
    """``torch.compile(fullgraph=True)``: ``@dispatch`` reads ``in_keys`` while tracing, so
    the keys are plain cached lists (CQLLoss's ``super()`` property would break the graph);
    with the same seed the compiled loss draws the same actions as the eager one."""
    loss, batch = _mock_loss(penalty_layout=layout), _mock_batch(0.5)
    torch.manual_seed(3)
    eager = loss(batch.clone())
    torch._dynamo.reset()
    compiled = torch.compile(loss, fullgraph=True, backend="eager")
    torch.manual_seed(3)
    out = compiled(batch.clone())
    assert set(out.keys()) == set(eager.keys()) == set(loss.out_keys)
    for key in loss.out_keys:
        torch.testing.assert_close(out[key], eager[key], msg=key)


# ----------------------------------------------------------------------------- Lagrange form
def test_the_lagrange_penalty_is_alpha_prime_times_the_penalty_minus_the_gap_by_hand():
    # Cal-QL's / CQL's reference code: α'·w·(diff_i − τ) per network, α' = exp(log α').
    loss = _mock_loss(min_q_weight=5.0, with_lagrange=True, lagrange_thresh=0.8)
    assert float(loss.log_alpha_prime.detach()) == 1.0  # the references' initial log α'
    batch = _mock_batch(0.3)
    td, value, _, draws = _spied_penalty(loss, batch)
    per_net, _ = _by_hand(loss, batch, batch["mc_return"], draws)
    expected = math.e * (per_net.mean(-1) - 5.0 * 0.8).sum()
    torch.testing.assert_close(value, expected)
    # the multiplier's loss: −½·α'·Σ_i (mean penalty_i − w·τ)
    prime_loss, _ = loss.alpha_prime_loss(td)
    torch.testing.assert_close(prime_loss, -0.5 * math.e * (per_net.mean(-1) - 4.0).sum())


def test_the_lagrange_gradients_reach_q_through_the_penalty_and_log_alpha_prime_only_by_its_loss():
    loss = _mock_loss(with_lagrange=True, lagrange_thresh=0.8)
    out = loss(_mock_batch(0.3))
    out["loss_cql"].backward(retain_graph=True)
    assert loss.log_alpha_prime.grad is None  # α' is a constant of the critic's penalty
    q_params = list(loss.qvalue_network_params.values(True, True))
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in q_params)
    for p in q_params:
        p.grad = None
    out["loss_alpha_prime"].backward()
    assert all(p.grad is None for p in q_params)  # the multiplier's loss moves log α' only
    excess = float(-out["loss_alpha_prime"].detach() / (0.5 * loss.log_alpha_prime.detach().exp()))
    # d loss / d log α' = loss (α' = exp(log α')): negative while the penalty exceeds w·τ
    torch.testing.assert_close(loss.log_alpha_prime.grad, out["loss_alpha_prime"].detach())
    assert (float(loss.log_alpha_prime.grad) < 0) == (excess > 0)


def test_a_multiplier_step_raises_alpha_prime_while_the_penalty_exceeds_the_gap_and_lowers_it_below():
    for gap, direction in ((-1e3, 1.0), (1e3, -1.0)):
        loss = _mock_loss(with_lagrange=True, lagrange_thresh=gap)
        before = float(loss.log_alpha_prime.detach())
        optimizer = torch.optim.SGD([loss.log_alpha_prime], lr=1e-4)
        loss(_mock_batch(0.3))["loss_alpha_prime"].backward()
        optimizer.step()
        assert (float(loss.log_alpha_prime.detach()) - before) * direction > 0


def test_torchrl_cqlloss_still_leaves_its_penalty_unweighted_by_the_lagrange_multiplier():
    # The TorchRL 0.14.1 behaviour CalQLLoss replaces: if this fails, TorchRL applies α' now
    # and CalQLLoss's Lagrange form (and its docstring) should be revisited.
    losses = []
    for log_alpha_prime in (0.0, 3.0):
        loss = _mock_loss(cls=CQLLoss, with_lagrange=True, lagrange_thresh=0.8)
        with torch.no_grad():
            loss.log_alpha_prime.fill_(log_alpha_prime)
        torch.manual_seed(1)
        losses.append(loss(_mock_batch())["loss_cql"])
    torch.testing.assert_close(losses[0], losses[1])
    loss = _mock_loss(cls=CQLLoss, with_lagrange=True, lagrange_thresh=0.8)
    loss(_mock_batch())["loss_alpha_prime"].backward()
    assert any(
        p.grad is not None and p.grad.abs().sum() > 0
        for p in loss.qvalue_network_params.values(True, True)
    )
