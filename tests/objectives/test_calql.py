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


def _penalty_by_hand(loss: CalQLLoss, batch: TensorDict, bound: torch.Tensor, seed: int = 1):
    """Cal-QL's penalty written out: the policy draws are spied, every Q is recomputed."""
    draws = []
    original = loss._get_policy_actions

    def spy(data, params, num_actions):
        out = original(data, params, num_actions=num_actions)
        draws.append(out)
        return out

    loss._get_policy_actions = spy
    value = _penalty(loss, batch, seed)
    del loss._get_policy_actions
    torch.manual_seed(seed)
    uniform = torch.empty(BATCH * NUM, ACT).uniform_(-1, 1)  # CQL's first draw
    (curr, curr_log_pi), (nxt, next_log_pi) = draws
    obs = batch["observation"].repeat_interleave(NUM, 0)
    g = bound.repeat_interleave(NUM)
    w, temp = loss.min_q_weight, loss.temperature
    total = torch.zeros(())
    for net in range(2):
        params = loss.qvalue_network_params[net]
        terms = torch.stack(
            [
                _q_by_hand(params, obs, uniform) - ACT * math.log(0.5),
                torch.maximum(_q_by_hand(params, obs, curr["action"]), g) - curr_log_pi,
                torch.maximum(_q_by_hand(params, obs, nxt["action"]), g) - next_log_pi,
            ],
            -1,
        ).reshape(BATCH, 3 * NUM)  # the 3·NUM actions of each state
        pred = _q_by_hand(params, batch["observation"], batch["action"])
        total = total + (w * (temp * torch.logsumexp(terms / temp, -1) - pred)).mean()
    return value, total


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


def test_with_the_bound_at_minus_inf_the_torchrl_layout_gives_cqllosss_outputs_exactly():
    cal, cql = _mock_loss(penalty_layout="torchrl"), _mock_loss(CQLLoss)
    batch = _mock_batch(-math.inf)
    torch.manual_seed(3)
    out_cal = cal(batch.clone())
    torch.manual_seed(3)
    out_cql = cql(batch.clone())
    for key in out_cql.keys():
        torch.testing.assert_close(out_cal[key], out_cql[key], rtol=1e-6, atol=1e-6)
    assert out_cal["bound_rate"] == 0


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
    assert "return_to_go" in loss.in_keys
    out = loss(batch.rename_key_("mc_return", "return_to_go"))
    assert "bound_rate" in out.keys()


def test_bad_layout_and_bound_shape_are_rejected():
    with pytest.raises(ValueError, match="penalty_layout='cql' is not one of"):
        _mock_loss(penalty_layout="cql")
    batch = _mock_batch(0.0)
    batch.set("mc_return", torch.zeros(BATCH, 2))
    with pytest.raises(ValueError, match="one return per transition"):
        _mock_loss()(batch)


def test_in_keys_list_cqlloss_s_then_the_bound_in_a_fixed_order():
    assert _mock_loss().in_keys == [*_mock_loss(cls=CQLLoss).in_keys, "mc_return"]
