"""``DiffQLActorLoss`` (Diff-QL's actor loss, Wang et al. 2023) as a TorchRL LossModule:
its value against a hand computation, its reductions, its keys, its graph.

The recipe-level tests (the critic's weights get no gradient, the Q-term's scale
invariance, Diff-QL's runs) are in ``tests/recipe/test_diffql.py``.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import DiffusionActor
from torchrl.objectives import LossModule

from torchrl_dual.objectives.diffql_actor_loss import DiffQLActorLoss, min_q

OBS, ACT, B = 3, 2, 16


def _actor(seed: int = 0) -> DiffusionActor:
    torch.manual_seed(seed)
    score = nn.Sequential(nn.Linear(ACT + OBS + 1, 16), nn.SiLU(), nn.Linear(16, ACT))
    return DiffusionActor(ACT, score_network=score, num_steps=3)


def _q_value(observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """A fixed critic: ``Q(s, a) = −‖a − 0.5‖² + s_0`` (negative and positive values)."""
    return -(action - 0.5).square().sum(-1) + observation[..., 0]


def _box(action: torch.Tensor) -> torch.Tensor:
    return action.clamp(-1.0, 1.0)


def _batch(seed: int = 1) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        observation=torch.randn(B, OBS, generator=gen),
        action=torch.rand(B, ACT, generator=gen) * 2 - 1,
        batch_size=[B],
    )


def _by_hand(loss: DiffQLActorLoss, batch: TensorDict, seed: int) -> tuple[torch.Tensor, ...]:
    """``L_bc`` (ε-prediction MSE at a random step, as TorchRL's DiffusionBCLoss draws it)
    and ``Q(s, a_π)`` of the actor's chain, recomputed from the same random stream."""
    torch.manual_seed(seed)
    ddpm = loss.actor.module
    t = torch.randint(0, ddpm.num_steps, (B,))
    noisy, noise = ddpm.add_noise(batch["action"], t)
    inputs = torch.cat([noisy, batch["observation"], t.float().unsqueeze(-1)], -1)
    bc = (ddpm.score_network(inputs) - noise).square()  # [B, ACT]
    q = _q_value(batch["observation"], loss.sample_actions(batch["observation"]))
    return bc, q


@pytest.mark.parametrize("eta", [0.0, 0.7, 2.5])
def test_the_loss_is_bc_plus_eta_times_the_normalised_q_term_by_hand(eta):
    loss = DiffQLActorLoss(_actor(), _q_value, _box, eta=eta)
    batch = _batch()
    torch.manual_seed(3)
    out = loss(batch)
    bc, q = _by_hand(loss, batch, seed=3)
    q_term = -q.mean() / q.abs().mean()
    torch.testing.assert_close(out["bc_term"], bc.mean())
    torch.testing.assert_close(out["q_term"], q_term)
    torch.testing.assert_close(out["q_pi"], q.mean())
    torch.testing.assert_close(out["loss_actor"], bc.mean() + eta * q_term)
    assert not out["bc_term"].requires_grad and not out["q_term"].requires_grad
    assert out["loss_actor"].requires_grad


def test_the_q_normaliser_is_detached_and_never_divides_by_zero():
    actor = _actor()
    zero = DiffQLActorLoss(actor, lambda s, a: 0.0 * a.sum(-1), _box, eta=1.0)
    out = zero(_batch())
    assert torch.isfinite(out["loss_actor"]) and out["q_term"] == 0  # |Q| clamped at 1e-6
    # detached normaliser: d(−mean Q / c)/dQ = −1 / (B c), c = mean |Q| held fixed
    q = torch.tensor([-2.0, 1.0, 3.0], requires_grad=True)
    loss = DiffQLActorLoss(actor, lambda s, a: q, _box, eta=1.0)
    q_term, _ = loss.q_term(torch.zeros(3, OBS))
    q_term.backward()
    torch.testing.assert_close(q.grad, torch.full((3,), -1.0 / (3 * 2.0)))
    # below 1 too: mean |Q| = 0.2 divides as it is (only a vanishing scale is clamped)
    small = torch.tensor([-0.2, 0.1, 0.3], requires_grad=True)
    loss = DiffQLActorLoss(actor, lambda s, a: small, _box, eta=1.0)
    q_term, _ = loss.q_term(torch.zeros(3, OBS))
    torch.testing.assert_close(q_term, torch.tensor(-0.2 / (3 * 0.2)))
    q_term.backward()
    torch.testing.assert_close(small.grad, torch.full((3,), -1.0 / (3 * 0.2)))


def test_reduction_none_is_per_sample_and_its_mean_and_sum_match_the_reduced_losses():
    batch = _batch()
    outs = {}
    for reduction in ("mean", "none", "sum"):  # each accepted at construction
        loss = DiffQLActorLoss(_actor(), _q_value, _box, eta=1.3, reduction=reduction)
        torch.manual_seed(4)
        outs[reduction] = loss(batch)
    mean = outs["mean"]
    none, total = outs["none"], outs["sum"]
    for key in ("loss_actor", "bc_term", "q_term"):
        assert none[key].shape == (B,), key
        torch.testing.assert_close(none[key].mean(), mean[key])
        torch.testing.assert_close(total[key], none[key].sum())
    assert none["q_pi"].shape == (B,)
    torch.testing.assert_close(none["q_pi"].mean(), mean["q_pi"])


def test_it_is_a_torchrl_loss_module_with_settable_keys():
    loss = DiffQLActorLoss(_actor(), _q_value, _box, eta=1.0)
    assert isinstance(loss, LossModule)
    assert loss.in_keys == ["observation", "action"]
    assert loss.out_keys == ["loss_actor", "bc_term", "q_term", "q_pi"]
    torch.manual_seed(5)
    expected = loss(_batch())
    loss.set_keys(observation="obs", action=("data", "act"))
    assert loss.in_keys == ["obs", ("data", "act")]
    assert loss.bc_loss.tensor_keys.observation == "obs"
    renamed = _batch().rename_key_("observation", "obs")
    renamed["data", "act"] = renamed.pop("action")
    torch.manual_seed(5)
    got = loss(renamed)
    for key in expected.keys():
        torch.testing.assert_close(got[key], expected[key])
    with pytest.raises(KeyError):
        loss(_batch())  # the old names are not read any more


def test_gradients_reach_every_actor_weight_and_a_bad_reduction_is_refused():
    actor = _actor()
    DiffQLActorLoss(actor, _q_value, _box, eta=1.0)(_batch())["loss_actor"].backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in actor.parameters())
    with pytest.raises(ValueError, match="reduction must be 'mean', 'sum' or 'none'"):
        DiffQLActorLoss(actor, _q_value, _box, eta=1.0, reduction="max")


def test_the_loss_on_iql_critics_compiles_without_a_graph_break():
    """``torch.compile(fullgraph=True)`` of the loss built by ``from_iql`` (issue 30): the
    DDPM chain, the twin critics' minimum (one ``to_module`` per member) and ``L_bc``."""
    from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
    from torchrl.objectives import IQLLoss

    torch.manual_seed(0)
    stand_in = ProbabilisticActor(
        TensorDictModule(nn.Linear(OBS, 2 * ACT), in_keys=["observation"], out_keys=["p"]),
        in_keys=["p"],
        distribution_class=torch.distributions.Normal,
    )
    critic = IQLLoss(
        stand_in,
        ValueOperator(MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
                      in_keys=["observation", "action"]),
        ValueOperator(MLP(in_features=OBS, out_features=1, num_cells=[8]),
                      in_keys=["observation"]),
        num_qvalue_nets=2,
    )  # fmt: skip
    loss = DiffQLActorLoss.from_iql(_actor(), critic, _box, eta=1.0)
    torch._dynamo.reset()
    out = torch.compile(loss, fullgraph=True, backend="eager")(_batch())
    assert torch.isfinite(out["loss_actor"])


def test_reduction_none_keeps_a_two_dimensional_batch():
    """``[2, 8]`` transitions: ``L_bc`` averaged over the action dimension only."""
    loss = DiffQLActorLoss(_actor(), _q_value, _box, eta=0.5, reduction="none")
    batch = _batch().reshape(2, B // 2)
    torch.manual_seed(6)
    out = loss(batch)
    assert out["loss_actor"].shape == out["bc_term"].shape == (2, B // 2)
    torch.manual_seed(6)
    flat = loss(_batch())
    torch.testing.assert_close(out["bc_term"].reshape(-1), flat["bc_term"])


def _iql_critic(seed: int = 0):
    """A TorchRL ``IQLLoss`` with twin ``Q(s, a)`` MLPs (its actor is a stand-in)."""
    from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
    from torchrl.objectives import IQLLoss

    torch.manual_seed(seed)
    stand_in = ProbabilisticActor(
        TensorDictModule(nn.Linear(OBS, 2 * ACT), in_keys=["observation"], out_keys=["p"]),
        in_keys=["p"],
        distribution_class=torch.distributions.Normal,
    )
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
        in_keys=["observation", "action"],
    )
    value = ValueOperator(MLP(in_features=OBS, out_features=1, num_cells=[8]), ["observation"])
    return IQLLoss(stand_in, qvalue, value, num_qvalue_nets=2)


def _q_by_hand(params, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
    """One member's MLP written out: ``W_1 tanh(W_0 [s, a] + b_0) + b_1`` (TorchRL MLP's Tanh)."""
    x = torch.cat([observation, action], -1)
    first, last = params["module", "0"], params["module", "2"]
    hidden = torch.tanh(x @ first["weight"].T + first["bias"])
    return (hidden @ last["weight"].T + last["bias"]).squeeze(-1)


def test_min_q_is_the_twin_minimum_with_gradients_to_the_action_only():
    critic = _iql_critic()
    params = critic.qvalue_network_params
    s, a = torch.randn(6, OBS), torch.rand(6, ACT, requires_grad=True)
    q = min_q(critic.qvalue_network, params, s, a)
    by_hand = torch.minimum(_q_by_hand(params[0], s, a), _q_by_hand(params[1], s, a))
    torch.testing.assert_close(q, by_hand)
    assert q.shape == (6,)
    q.sum().backward()
    assert a.grad is not None and a.grad.abs().sum() > 0
    assert all(p.grad is None for p in params.values(True, True))  # the critic's detached
    renamed = TensorDictModule(
        critic.qvalue_network.module, ["observation", "action"], ["my_q"]
    )  # the Q under another output key
    torch.testing.assert_close(min_q(renamed, params, s, a, key="my_q"), by_hand)


def test_from_iql_reads_the_current_twin_critics_minimum():
    critic = _iql_critic()
    with torch.no_grad():  # the target copies differ from the current weights
        for p in critic.target_qvalue_network_params.values(True, True):
            p.add_(1.0)
    q_value = DiffQLActorLoss.from_iql(_actor(), critic, _box, eta=1.0).q_value
    s, a = torch.randn(5, OBS), torch.rand(5, ACT)
    params = critic.qvalue_network_params
    by_hand = torch.minimum(_q_by_hand(params[0], s, a), _q_by_hand(params[1], s, a))
    torch.testing.assert_close(q_value(s, a), by_hand)
    loss = DiffQLActorLoss.from_iql(_actor(), critic, _box, eta=0.25, reduction="none")
    assert loss.eta == 0.25 and loss.reduction == "none"
