"""``CalQLLoss.forward`` and ``critic_terms`` (one pass: the actor once per state, the
penalty's draws from its repeated parameters, the Q networks by ``EnsembleMLP``) against
the same losses computed TorchRL's way: ``CQLLoss.forward`` and ``q_loss`` /
``cql_loss`` / ``alpha_prime_loss`` with ``CQLLoss._get_policy_actions`` (the actor run
on ``num_random`` copies of the inputs) and TorchRL's vmapped Q calls.

Bit for bit with actors that compute each state's distribution on its own row (entry by
entry here): everything else is the same operations on the same inputs. An MLP actor's
matrix products may round a row differently in a batch of ``B`` than of ``B·num_random``
rows (MKL does for tiny layers, not at the recipe's 256 x 2: its smoke runs are
identical), so with one the losses agree to float rounding."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import CQLLoss
from torchrl.objectives.utils import _vmap_func
from toy import tanh_normal_actor

from torchrl_dual.modules.actors.action_box import ClippedNormal
from torchrl_dual.objectives import CalQLLoss
from torchrl_dual.objectives.ensemble_q import EnsembleMLP

OBS, ACT, BATCH, NUM = 3, 2, 6, 4
SPEC = Bounded(-torch.ones(ACT), torch.ones(ACT), (ACT,))


class _EntryWise(nn.Module):
    """``s -> (μ(s), σ(s))`` entry by entry on ``s``'s first ``ACT`` components, so each
    state's parameters are the same alone or in any batch; with ``shared_scale`` one
    learned ``σ`` per action dimension broadcast over the batch (an expanded view, as
    DUAL's ``policy_view`` gives it)."""

    def __init__(self, shared_scale: bool) -> None:
        super().__init__()
        self.weight = nn.Parameter(torch.tensor([0.7, -1.3]))
        self.bias = nn.Parameter(torch.tensor([0.1, 0.2]))
        self.log_std = nn.Parameter(torch.tensor([-0.5, -0.2]))
        self.shared_scale = shared_scale

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = observation[..., :ACT]
        loc = x * self.weight + self.bias
        if self.shared_scale:
            return loc, self.log_std.exp().expand_as(loc)
        return loc, (0.3 * x + self.log_std).exp()


def _actor(kind: str) -> ProbabilisticActor:
    if kind == "mlp":
        return tanh_normal_actor(OBS, ACT, SPEC)
    clipped = kind == "clipped_shared_scale"
    return ProbabilisticActor(
        TensorDictModule(_EntryWise(clipped), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=SPEC,
        distribution_class=ClippedNormal if clipped else TanhNormal,
        distribution_kwargs={"low": -1.0, "high": 1.0} if clipped else {},
    )


def _loss(kind: str = "tanh_normal", **kwargs) -> CalQLLoss:
    torch.manual_seed(0)
    actor = _actor(kind)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8, 8], activation_class=nn.ReLU),
        in_keys=["observation", "action"],
    )
    loss = CalQLLoss(actor, qvalue, num_random=NUM, min_q_weight=3.0, **kwargs)
    loss.make_value_estimator(gamma=0.9)
    with torch.no_grad():  # the target Q networks away from the online ones
        loss.target_qvalue_network_params.apply(lambda p: p.add_(0.05))
    return loss


def _torchrl_way(loss: CalQLLoss) -> CalQLLoss:
    """``loss`` sampling the penalty's actions with ``CQLLoss._get_policy_actions`` and
    evaluating its Q networks with TorchRL's vmapped call."""
    loss._vmap_qvalue_networkN0 = _vmap_func(
        loss.qvalue_network, (None, 0), randomness=loss.vmap_randomness
    )

    def policy_actions(data, params, num_actions=10, dist_params=None):
        return CQLLoss._get_policy_actions(loss, data.copy(), params, num_actions)

    loss._get_policy_actions = policy_actions
    return loss


def _batch(bound: float = 0.3) -> TensorDict:
    gen = torch.Generator().manual_seed(1)
    return TensorDict(
        {
            "observation": torch.randn(BATCH, OBS, generator=gen),
            "action": torch.rand(BATCH, ACT, generator=gen) * 2 - 1,
            "mc_return": torch.tensor([5.0, -5.0, 0.2, -math.inf, bound, -1.0]).unsqueeze(-1),
            ("next", "observation"): torch.randn(BATCH, OBS, generator=gen),
            ("next", "reward"): torch.randn(BATCH, 1, generator=gen),
            ("next", "done"): torch.tensor([0, 0, 1, 0, 0, 0], dtype=torch.bool).unsqueeze(-1),
            ("next", "terminated"): torch.tensor([0, 0, 1, 0, 0, 0], dtype=torch.bool)[:, None],
        },
        [BATCH],
    )


def _rows_stable(loss: CalQLLoss) -> bool:
    """Whether the actor gives each state the same parameters alone in a batch of
    ``BATCH`` as repeated ``NUM`` times (the BLAS's row stability on this machine)."""
    obs = _batch()["observation"]
    with torch.no_grad(), loss.actor_network_params.to_module(loss.actor_network):
        once = loss.actor_network.get_dist_params(TensorDict(observation=obs, batch_size=[BATCH]))
        many = loss.actor_network.get_dist_params(
            TensorDict(observation=obs.repeat_interleave(NUM, 0), batch_size=[BATCH * NUM])
        )
    return all(torch.equal(once[k].repeat_interleave(NUM, 0), many[k]) for k in ("loc", "scale"))


def _exact(loss: CalQLLoss, case: dict) -> bool:
    """Bit for bit unless an MLP actor's rows round differently in a larger batch."""
    exact = _rows_stable(loss)
    assert exact or case.get("kind") == "mlp"  # entry-wise actors: by construction
    return exact


def _check(got: torch.Tensor, expected: torch.Tensor, exact: bool, name: str) -> None:
    if exact:
        assert torch.equal(got, expected), name
    else:
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5, msg=name)


def _grads(loss: CalQLLoss) -> dict[str, torch.Tensor | None]:
    return {name: p.grad for name, p in loss.named_parameters()}


def _check_grads(fast: CalQLLoss, reference: CalQLLoss, exact: bool) -> None:
    expected, got = _grads(reference), _grads(fast)
    assert expected.keys() == got.keys()
    assert any(g is not None and g.abs().sum() > 0 for g in got.values())
    for name, grad in expected.items():
        if grad is None:
            assert got[name] is None, name
        else:
            _check(got[name], grad, exact, name)


CASES = [
    {},
    {"with_lagrange": True, "lagrange_thresh": 0.8},
    {"penalty_layout": "torchrl"},
    {"kind": "clipped_shared_scale"},
    {"deterministic_backup": False},
    {"kind": "mlp"},
    {"kind": "mlp", "with_lagrange": True, "lagrange_thresh": 0.8},
]


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(map(str, c.values())) or "default")
def test_critic_terms_are_q_loss_cql_loss_and_alpha_prime_loss_the_torchrl_way(case):
    fast, reference = _loss(**case), _torchrl_way(_loss(**case))
    exact = _exact(fast, case)
    batch = _batch()
    torch.manual_seed(7)
    td = batch.clone()
    expected = {"loss_qvalue": reference.q_loss(td)[0], "loss_cql": reference.cql_loss(td)[0]}
    if reference.with_lagrange:
        expected["loss_alpha_prime"] = reference.alpha_prime_loss(td)[0]
    torch.manual_seed(7)
    fast_td = batch.clone()
    got = fast.critic_terms(fast_td)
    assert list(got) == list(expected)
    for name, value in expected.items():
        _check(got[name], value, exact, name)
    for key in ("pred_q1", "pred_q2", "cql_q1_loss", "cql_q2_loss", "bound_rate"):
        _check(fast_td[key], td[key], exact, key)
    assert 0 < float(fast_td["bound_rate"].mean()) < 1  # some policy Q-values raised
    sum(expected.values()).backward()
    sum(got.values()).backward()
    _check_grads(fast, reference, exact)


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(map(str, c.values())) or "default")
def test_forward_is_cqlloss_forward_the_torchrl_way_plus_the_bound_rate(case):
    fast, reference = _loss(**case), _torchrl_way(_loss(**case))
    exact = _exact(fast, case)
    batch = _batch()
    torch.manual_seed(7)
    td = batch.clone()
    expected = CQLLoss.forward(reference, td)
    torch.manual_seed(7)
    fast_td = batch.clone()
    got = fast(fast_td)
    assert list(got.keys()) == [*expected.keys(), "bound_rate"]
    for key in expected.keys():
        _check(got[key], expected[key], exact, key)
    _check(got["bound_rate"], td["bound_rate"].mean(), exact, "bound_rate")
    _check(fast_td["td_error"], td["td_error"], exact, "td_error")
    trained = ["loss_qvalue", "loss_cql", "loss_actor", "loss_alpha"]
    if fast.with_lagrange:
        trained.append("loss_alpha_prime")
    sum(expected[key] for key in trained).backward()
    sum(got[key] for key in trained).backward()
    _check_grads(fast, reference, exact)


def test_forward_with_reduction_none_gives_per_transition_losses_the_torchrl_way():
    kwargs = {"reduction": "none", "scalar_output_mode": "exclude"}
    fast, reference = _loss(**kwargs), _torchrl_way(_loss(**kwargs))
    exact = _exact(fast, kwargs)
    torch.manual_seed(7)
    expected = CQLLoss.forward(reference, td := _batch())
    torch.manual_seed(7)
    got = fast(_batch())
    assert got.batch_size == (BATCH,)
    for key in expected.keys():
        _check(got[key], expected[key], exact, key)
    _check(got["bound_rate"], td["bound_rate"], exact, "bound_rate")


def test_the_penalty_s_q_calls_are_ensemble_mlp_and_other_batch_shapes_are_vmapped():
    loss = _loss()
    assert isinstance(loss._vmap_qvalue_networkN0, EnsembleMLP)
    assert not isinstance(_loss(deactivate_vmap=True)._vmap_qvalue_networkN0, EnsembleMLP)
    # a [2, 3] batch: EnsembleMLP hands it to vmap; the losses keep their [2, 3] shape
    per_row = _loss(reduction="none", scalar_output_mode="exclude")
    out = per_row(_batch().reshape(2, 3))
    assert out["loss_cql"].shape == (2, 3) and out["bound_rate"].shape == (2, 3)
