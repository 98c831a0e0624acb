"""``EnsembleMLP``: TorchRL's vmapped twin-Q call, bit for bit, values and gradients."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictParams
from torch import nn
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives.utils import _vmap_func

from torchrl_dual.objectives.ensemble_q import EnsembleMLP

OBS, ACT = 5, 2


def _twin(activation: type[nn.Module] = nn.ReLU, cells=(32, 32), **kwargs):
    torch.manual_seed(0)
    q = ValueOperator(
        MLP(
            in_features=OBS + ACT,
            out_features=1,
            num_cells=list(cells),
            activation_class=activation,
            **kwargs,
        ),
        in_keys=["observation", "action"],
    )
    other = copy.deepcopy(q)
    with torch.no_grad():
        for p in other.parameters():
            p.add_(0.1 * torch.randn_like(p))
    params = TensorDictParams(TensorDict.from_modules(q, other, as_module=True))
    vmapped = _vmap_func(q, (None, 0), randomness="error")
    return q, params, vmapped


def _evaluate(call, params, batch: int, wrt: str):
    """Q-values of ``call`` on a seeded batch, and the gradients of a weighted sum of them
    to the parameters (``wrt="params"``) or to the actions through detached parameters
    (``wrt="action"``, as SAC's actor loss reads Q)."""
    gen = torch.Generator().manual_seed(batch)
    action = torch.rand(batch, ACT, generator=gen) * 2 - 1
    action.requires_grad_(wrt == "action")
    data = TensorDict(
        observation=torch.randn(batch, OBS, generator=gen), action=action, batch_size=[batch]
    )
    for p in params.values(True, True):
        p.grad = None
    q = call(data, params.detach() if wrt == "action" else params)["state_action_value"]
    (q * torch.randn(q.shape, generator=gen)).sum().backward()
    grads = [p.grad for p in params.values(True, True)] if wrt == "params" else [action.grad]
    return q.detach(), grads


@pytest.mark.parametrize("activation", [nn.ReLU, nn.Tanh])
@pytest.mark.parametrize("batch", [1, 6, 40, 256])
@pytest.mark.parametrize("wrt", ["params", "action"])
def test_values_and_gradients_are_the_vmapped_calls_bitwise(activation, batch, wrt):
    q, params, vmapped = _twin(activation)
    fast = EnsembleMLP.of(q, vmapped)
    assert isinstance(fast, EnsembleMLP)
    expected, expected_grads = _evaluate(vmapped, params, batch, wrt)
    got, grads = _evaluate(fast, params, batch, wrt)
    assert got.shape == (2, batch, 1)
    assert torch.equal(got, expected)
    assert len(grads) == len(expected_grads)
    for g, e in zip(grads, expected_grads, strict=True):
        assert g is not None and torch.equal(g, e)


def test_one_hidden_layer_and_no_hidden_layer_networks():
    for cells in ((16,), ()):
        q, params, vmapped = _twin(cells=cells)
        fast = EnsembleMLP.of(q, vmapped)
        expected, expected_grads = _evaluate(vmapped, params, 8, "params")
        got, grads = _evaluate(fast, params, 8, "params")
        assert torch.equal(got, expected), cells
        assert all(torch.equal(g, e) for g, e in zip(grads, expected_grads, strict=True))


def test_other_batch_shapes_go_to_the_vmapped_call():
    q, params, vmapped = _twin()
    calls = []

    def fallback(data, p):
        calls.append(data.batch_size)
        return vmapped(data, p)

    fast = EnsembleMLP.of(q, fallback)
    data = TensorDict(
        observation=torch.randn(2, 3, OBS), action=torch.rand(2, 3, ACT), batch_size=[2, 3]
    )
    assert fast(data, params)["state_action_value"].shape == (2, 2, 3, 1)
    assert calls == [torch.Size([2, 3])]


def test_networks_other_than_a_plain_one_output_mlp_keep_the_vmapped_call():
    vmapped = object()
    others = [
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8], activate_last_layer=True),
        MLP(in_features=OBS + ACT, out_features=2, num_cells=[8]),
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8], dropout=0.1),
        nn.Sequential(nn.Linear(OBS + ACT, 8), nn.ReLU(), nn.Linear(8, 1)),
    ]
    for module in others:
        q = ValueOperator(module, in_keys=["observation", "action"])
        assert EnsembleMLP.of(q, vmapped) is vmapped, module
    plain = TensorDictModule(
        MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
        in_keys=["observation", "action"],
        out_keys=["state_action_value"],
    )
    assert EnsembleMLP.of(plain, vmapped) is vmapped  # not a ValueOperator


def test_the_packages_twin_q_calls_are_ensemble_mlps_with_the_vmapped_numbers():
    """DUAL's critic (``IQLCriticLoss``), the IQL baseline's ``OnePassIQLLoss`` and Eq. 7's
    weights (``WeightedMAPActorLoss``) call their twin Q as ``EnsembleMLP``: TorchRL's
    vmapped numbers, without its overhead."""
    from torchrl.modules import ProbabilisticActor, TanhNormal

    from torchrl_dual.modules import LinearHeadActor
    from torchrl_dual.objectives import IQLCriticLoss, OnePassIQLLoss, WeightedMAPActorLoss

    q, _, vmapped = _twin()
    value = ValueOperator(MLP(in_features=OBS, out_features=1, num_cells=[8]), ["observation"])
    critic = IQLCriticLoss(q, value)
    assert isinstance(critic._vmap_qvalue_networkN0, EnsembleMLP)
    policy = ProbabilisticActor(
        TensorDictModule(nn.Linear(OBS, 2 * ACT), ["observation"], ["param"]),
        in_keys=["param"],
        distribution_class=TanhNormal,
    )
    assert isinstance(OnePassIQLLoss(policy, q, value)._vmap_qvalue_networkN0, EnsembleMLP)
    actor = LinearHeadActor(MLP(in_features=OBS, out_features=8, num_cells=[8]), ACT)
    eq7 = WeightedMAPActorLoss.from_iql(actor, critic)
    data = TensorDict(observation=torch.randn(6, OBS), action=torch.rand(6, ACT), batch_size=[6])
    targets = critic.target_qvalue_network_params.detach()
    expected = vmapped(data, targets)["state_action_value"].min(0).values.squeeze(-1)
    assert torch.equal(eq7.q_value(data), expected)
    assert [type(call) for call in eq7._ensemble_calls.values()] == [EnsembleMLP]
    eq7.set_vmap_randomness("different")  # TorchRL's hook: rebuilt at the next call
    assert eq7._ensemble_calls == {}
