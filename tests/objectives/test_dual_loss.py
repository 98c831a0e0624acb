"""DUALLoss: DUAL's actor-critic update as one TorchRL loss (Alg. 1 lines 7-8 / 15-16)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import IQLLoss, SoftUpdate

from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.modules.actors.action_box import ClippedNormal
from torchrl_dual.objectives import (
    CalQLLoss,
    DUALLoss,
    IQLCriticLoss,
    SO2QLoss,
    WeightedMAPActorLoss,
)
from torchrl_dual.trainers import CriticActorStepper

OBS, ACT = 3, 2
BOX = Bounded(-1.0, 1.0, shape=(ACT,))


def batch(n: int = 16, seed: int = 0) -> TensorDict:
    gen = torch.Generator().manual_seed(seed)
    return TensorDict(
        {
            "observation": torch.randn(n, OBS, generator=gen),
            "action": torch.rand(n, ACT, generator=gen) * 2 - 1,
            "next": {
                "observation": torch.randn(n, OBS, generator=gen),
                "reward": torch.randn(n, 1, generator=gen),
                "done": torch.zeros(n, 1, dtype=torch.bool),
                "terminated": torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        [n],
    )


def networks(seed: int = 0):
    torch.manual_seed(seed)
    actor = LinearHeadActor(MLP(in_features=OBS, out_features=ACT, num_cells=[16]), ACT)
    qvalue = ValueOperator(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[16]), ["observation", "action"]
    )
    value = ValueOperator(MLP(in_features=OBS, out_features=1, num_cells=[16]), ["observation"])
    return actor, qvalue, value


def dual_loss(seed: int = 0, **kwargs) -> DUALLoss:
    actor, qvalue, value = networks(seed)
    critic = IQLCriticLoss(qvalue, value, loss_function="l2", expectile=0.7)
    loss = DUALLoss(actor, critic, **kwargs)
    loss.make_value_estimator(gamma=0.99)
    return loss


def test_forward_returns_every_term_and_the_actor_metrics():
    out = dual_loss()(batch())
    assert set(out.keys()) == {
        "loss_qvalue",
        "loss_value",
        "loss_actor",
        "weight_mean",
        "log_prob",
        "actor_std",
    }
    assert all(out[k].shape == () for k in out.keys())
    assert out["loss_qvalue"].requires_grad and out["loss_actor"].requires_grad
    assert not out["weight_mean"].requires_grad


def test_each_term_reaches_its_own_parameters_and_never_a_target():
    loss = dual_loss()
    critic_ids = {id(p) for p in loss.critic_parameters()}
    actor_ids = {id(p) for p in loss.actor_parameters()}
    assert critic_ids and actor_ids and not critic_ids & actor_ids
    targets = list(loss.target_qvalue_network_params.values(True, True))
    for term, own in (
        ("loss_qvalue", critic_ids),
        ("loss_value", critic_ids),
        ("loss_actor", actor_ids),
    ):
        loss.zero_grad(set_to_none=True)
        loss(batch())[term].backward()
        touched = {
            id(p) for p in loss.parameters() if p.grad is not None and p.grad.abs().sum() > 0
        }
        assert touched and touched <= own, term
        assert all(t.grad is None for t in targets)


def test_the_stepper_is_the_hand_written_update_of_torchrl_parts_bitwise():
    """CriticActorStepper(DUALLoss) against TorchRL's IQLLoss critic terms, SoftUpdate,
    WeightedMAPActorLoss and two Adams written out by hand (Alg. 1's order), 5 updates."""
    loss = dual_loss(seed=1, temperature=3.0)
    stepper = CriticActorStepper(
        loss,
        torch.optim.Adam(loss.critic_parameters(), lr=1e-2),
        torch.optim.Adam(loss.actor_parameters(), lr=1e-2),
        target_update=SoftUpdate(loss, tau=0.1),
    )
    actor, qvalue, value = networks(seed=1)

    class Stand(nn.Module):  # the actor slot TorchRL's IQLLoss cannot leave empty
        def forward(self, observation):
            raise RuntimeError

    iql = IQLLoss(
        ProbabilisticActor(
            TensorDictModule(Stand(), ["observation"], ["loc", "scale"]),
            in_keys=["loc", "scale"],
            distribution_class=torch.distributions.Normal,
        ),
        qvalue,
        value,
        loss_function="l2",
        expectile=0.7,
    )
    iql.make_value_estimator(gamma=0.99)
    target = SoftUpdate(iql, tau=0.1)
    actor_loss = WeightedMAPActorLoss.from_iql(actor, iql, temperature=3.0)
    critic_opt = torch.optim.Adam(
        [
            *iql.qvalue_network_params.values(True, True),
            *iql.value_network_params.values(True, True),
        ],
        lr=1e-2,
    )
    actor_opt = torch.optim.Adam(actor_loss.parameters(), lr=1e-2)
    for step in range(5):
        data = batch(seed=step)
        out = stepper.update(data.clone())
        critic = iql.qvalue_loss(data)[0] + iql.value_loss(data)[0]
        critic_opt.zero_grad()
        critic.backward()
        critic_opt.step()
        target.step()
        reference = actor_loss(data)["loss_actor"]
        actor_opt.zero_grad()
        reference.backward()
        actor_opt.step()
        assert torch.equal(out["loss_actor"], reference.detach())
    for mine, theirs in (
        (loss.qvalue_network_params, iql.qvalue_network_params),
        (loss.target_qvalue_network_params, iql.target_qvalue_network_params),
        (loss.value_network_params, iql.value_network_params),
        (loss.actor_params, actor_loss.actor_params),
    ):
        assert (mine == theirs).all()


def test_one_optimizer_on_the_summed_terms_trains_critic_and_actor():
    """TorchRL's way: one Adam over loss.parameters(), the sum of the loss_* terms, and
    SoftUpdate(loss): the critic fits a fixed reward, the actor its weighted data."""
    loss = dual_loss(seed=2)
    optimizer = torch.optim.Adam(loss.parameters(), lr=3e-3)
    updater = SoftUpdate(loss, tau=0.05)
    data = batch(64, seed=3)
    data["next", "done"] = data["next", "terminated"] = torch.ones(64, 1, dtype=torch.bool)
    data["next", "reward"] = data["observation"].sum(-1, keepdim=True)  # Q = r: learnable
    first = last = None
    for _ in range(300):
        out = loss(data.clone())
        total = sum(out[k] for k in out.keys() if k.startswith("loss_"))
        optimizer.zero_grad()
        total.backward()
        optimizer.step()
        updater.step()
        first = first or {k: out[k].item() for k in ("loss_qvalue", "loss_actor")}
        last = {k: out[k].item() for k in ("loss_qvalue", "loss_actor")}
    assert last["loss_qvalue"] < 0.2 * first["loss_qvalue"]
    assert last["loss_actor"] < first["loss_actor"]


def test_soft_update_finds_the_critic_targets_on_the_loss():
    loss = dual_loss()
    updater = SoftUpdate(loss, tau=0.5)
    with torch.no_grad():
        loss.qvalue_network_params.apply_(lambda p: p.add_(1.0))
    before = loss.target_qvalue_network_params.clone()
    updater.step()
    moved = loss.target_qvalue_network_params - before
    assert torch.allclose(
        moved.flatten_keys()["module.0.bias"],
        torch.full_like(moved.flatten_keys()["module.0.bias"], 0.5),
    )
    assert loss.critic.target_qvalue_network_params is loss.target_qvalue_network_params


def test_state_dict_round_trip_restores_every_term():
    trained, fresh = dual_loss(seed=0), dual_loss(seed=5)
    data = batch()
    assert not torch.equal(trained(data.clone())["loss_qvalue"], fresh(data.clone())["loss_qvalue"])
    keys = set(trained.state_dict())
    assert {"actor_params.log_std", "qvalue_network_params.module.0.weight"} <= keys
    assert any(k.startswith("target_qvalue_network_params") for k in keys)
    fresh.load_state_dict(trained.state_dict())
    mine, theirs = trained(data.clone()), fresh(data.clone())
    assert all(torch.equal(mine[k], theirs[k]) for k in mine.keys())


def test_a_cast_carries_the_critic_and_the_actor():
    loss = dual_loss().double()
    assert loss.critic.qvalue_network_params is loss.qvalue_network_params
    assert loss.critic.value_estimator.gamma.dtype == torch.float64
    out = loss(batch().apply(lambda t: t.double() if t.is_floating_point() else t))
    assert out["loss_qvalue"].dtype == out["loss_actor"].dtype == torch.float64


def test_set_keys_renames_in_both_parts_and_rejects_unknown_names():
    actor, qvalue, value = networks()
    qvalue = ValueOperator(qvalue.module, ["obs", "act"], out_keys=["state_action_value"])
    value = ValueOperator(value.module, ["obs"])
    loss = DUALLoss(actor, IQLCriticLoss(qvalue, value))
    loss.set_keys(observation="obs", action="act")
    loss.make_value_estimator(gamma=0.99)
    data = batch().rename_key_("observation", "obs").rename_key_("action", "act")
    data["next"].rename_key_("observation", "obs")
    out = loss(data)
    assert torch.isfinite(out["loss_actor"]) and torch.isfinite(out["loss_value"])
    with pytest.raises(ValueError, match="not keys of DUALLoss"):
        loss.set_keys(observaton="obs")


def test_a_nan_reward_is_named_with_its_batch_index():
    data = batch()
    data["next", "reward"][5] = float("nan")
    with pytest.raises(
        ValueError, match=r"DUALLoss's loss_qvalue holds a NaN or inf.*'next', 'reward'.*index 5"
    ):
        dual_loss()(data)
    assert torch.isfinite(dual_loss(check_finite=False)(batch())["loss_qvalue"])


def test_a_critic_without_the_protocol_is_refused():
    actor, qvalue, value = networks()
    with pytest.raises(TypeError, match="critic protocol"):
        DUALLoss(actor, qvalue)


def test_reset_parameters_recursive_reinitialises_the_actor_and_the_critic():
    loss = dual_loss()
    before = {k: v.clone() for k, v in loss.state_dict().items()}
    loss.reset_parameters_recursive()
    after = loss.state_dict()
    for key in (
        "actor_params.trunk.0.weight",
        "qvalue_network_params.module.0.weight",
        "value_network_params.module.0.weight",
    ):
        assert not torch.equal(before[key], after[key]), key


def _policy(actor):
    from tensordict.nn import TensorDictModule as Module

    class MeanStd(nn.Module):
        def __init__(self):
            super().__init__()
            self.actor = actor

        def forward(self, observation):
            loc = self.actor(observation)
            return loc, self.actor.std.expand_as(loc)

    return ProbabilisticActor(
        Module(MeanStd(), ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=BOX,
        distribution_class=ClippedNormal,
        distribution_kwargs={"low": -torch.ones(ACT), "high": torch.ones(ACT)},
        return_log_prob=True,
    )


@pytest.mark.parametrize("kind", ["calql", "so2"])
def test_cal_ql_and_so2_critics_use_the_same_interface(kind):
    actor, qvalue, _ = networks()
    if kind == "calql":
        critic = CalQLLoss(_policy(actor), qvalue, num_random=2, action_spec=BOX)
        expected = {"loss_qvalue", "loss_cql"}
    else:
        critic = SO2QLoss(_policy(actor), qvalue, action_spec=BOX, num_qvalue_nets=3)
        expected = {"loss_qvalue"}
    loss = DUALLoss(actor, critic, weighting="sac", action_spec=BOX)
    loss.make_value_estimator(gamma=0.99)
    data = batch()
    data["mc_return"] = torch.zeros(16, 1)
    out = loss(data)
    assert set(loss.critic.critic_out_keys) == expected
    assert expected | {"loss_actor"} <= set(out.keys())
    # the critic's policy reads the actor's own weights: held once, by the actor's part
    assert not any(k.startswith("actor_network_params") for k in loss.state_dict())
    SoftUpdate(loss, tau=0.005).step()
