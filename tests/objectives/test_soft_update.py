"""``ForeachSoftUpdate``: TorchRL's ``SoftUpdate``, bitwise, in one fused kernel."""

from __future__ import annotations

import copy

import pytest
import torch
from torchrl.modules import MLP, Actor, ValueOperator
from torchrl.objectives import DDPGLoss, SoftUpdate
from toy import tiny_iql_loss

from torchrl_dual.objectives import ForeachSoftUpdate


def _ddpg_loss() -> DDPGLoss:
    """Two target groups (actor and value networks)."""
    torch.manual_seed(0)
    actor = Actor(MLP(in_features=3, out_features=2, num_cells=[8]))
    value = ValueOperator(
        MLP(in_features=5, out_features=1, num_cells=[8]), in_keys=["observation", "action"]
    )
    return DDPGLoss(actor, value, delay_actor=True, delay_value=True)


LOSSES = {"iql": lambda: tiny_iql_loss(seed=0), "ddpg": _ddpg_loss}


def _perturb(loss: torch.nn.Module, step: int) -> None:
    """Moves every trained weight, as an optimizer step would."""
    gen = torch.Generator().manual_seed(step)
    with torch.no_grad():
        for p in loss.parameters():
            p.add_(torch.randn(p.shape, generator=gen) * 0.1)


def _targets(loss: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in loss.state_dict().items() if k.startswith("target_")}


@pytest.mark.parametrize("name", sorted(LOSSES))
@pytest.mark.parametrize("tau", [0.005, 0.3])
def test_steps_are_torchrl_soft_update_bitwise(name, tau):
    reference = LOSSES[name]()
    fused = copy.deepcopy(reference)
    ref_updater, updater = SoftUpdate(reference, tau=tau), ForeachSoftUpdate(fused, tau=tau)
    before = _targets(fused)
    for step in range(5):
        _perturb(reference, step)
        _perturb(fused, step)
        ref_updater.step()
        updater.step()
    expected, got = _targets(reference), _targets(fused)
    assert expected.keys() == got.keys() and got
    for key, value in expected.items():
        assert torch.equal(got[key], value), key
    assert any(not torch.equal(got[k], before[k]) for k in got)  # the targets moved


def test_sources_are_left_alone():
    loss = tiny_iql_loss(seed=0)
    updater = ForeachSoftUpdate(loss, tau=0.5)
    _perturb(loss, 0)
    sources = {k: v.clone() for k, v in loss.state_dict().items() if not k.startswith("target_")}
    updater.step()
    state = loss.state_dict()
    assert all(torch.equal(state[k], v) for k, v in sources.items())


def test_a_target_in_a_graph_is_refused_as_torchrl_does():
    loss = tiny_iql_loss(seed=0)
    updater = ForeachSoftUpdate(loss, tau=0.5)
    leaf = next(iter(loss.target_qvalue_network_params.values(True, True)))
    leaf.requires_grad_(True)
    with pytest.raises(RuntimeError, match="part of a graph"):
        updater.step()
