"""``torchrl_dual.objectives.optim.adam``: PyTorch's fused Adam wherever it applies, the
same arithmetic as the per-parameter loop up to rounding, and steps the acting caches see."""

from __future__ import annotations

import torch

from torchrl_dual.objectives import progressive_distillation, train_planner
from torchrl_dual.objectives.optim import adam


def test_float_parameters_on_the_cpu_get_the_fused_kernel():
    assert adam(torch.nn.Linear(3, 2).parameters(), lr=1e-3).param_groups[0]["fused"]
    assert not adam(torch.nn.Linear(3, 2).parameters(), lr=1e-3, fuse=False).param_groups[0][
        "fused"
    ]


def test_parameters_the_kernel_cannot_take_fall_back_to_the_default():
    meta = torch.nn.Linear(3, 2, device="meta")  # TorchRL stores actors with meta params
    assert not adam(meta.parameters(), lr=1e-3).param_groups[0]["fused"]
    mixed = [*torch.nn.Linear(3, 2).parameters(), *meta.parameters()]  # one group, one kernel
    assert not adam(mixed, lr=1e-3).param_groups[0]["fused"]


def test_the_fused_steps_match_the_per_parameter_loop_up_to_rounding():
    torch.manual_seed(0)
    fused_net, loop_net = torch.nn.Linear(8, 4), torch.nn.Linear(8, 4)
    loop_net.load_state_dict(fused_net.state_dict())
    fused, loop = adam(fused_net.parameters(), 1e-2), adam(loop_net.parameters(), 1e-2, fuse=False)
    start = fused_net.weight.detach().clone()
    x = torch.randn(32, 8)
    for _ in range(20):
        for net, opt in ((fused_net, fused), (loop_net, loop)):
            opt.zero_grad()
            net(x).pow(2).mean().backward()
            opt.step()
    for a, b in zip(fused_net.parameters(), loop_net.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert (fused_net.weight - start).abs().max() > 0.05  # it did train


def test_a_fused_step_moves_the_version_counters_the_acting_caches_read():
    net = torch.nn.Linear(3, 2)
    optimizer = adam(net.parameters(), lr=1e-3)
    assert optimizer.param_groups[0]["fused"]  # PyTorch's fused step moves none itself
    before = net.weight._version
    net(torch.ones(1, 3)).sum().backward()
    optimizer.step()
    assert net.weight._version > before


def test_the_planner_and_distillation_drivers_train_with_it(monkeypatch, make_model, make_windows):
    built = []

    def recording_adam(params, lr, **kwargs):
        optimizer = adam(params, lr, **kwargs)
        built.append(optimizer)
        return optimizer

    monkeypatch.setattr("torchrl_dual.objectives.diffusion_planner.adam", recording_adam)
    monkeypatch.setattr("torchrl_dual.objectives.distillation.adam", recording_adam)
    model = make_model(num_steps=4)

    def sample():
        return make_windows()

    train_planner(model, sample, 2, progress=False)
    progressive_distillation(model, sample, [1, 1], progress=False)
    assert len(built) == 3 and all(o.param_groups[0]["fused"] for o in built)
