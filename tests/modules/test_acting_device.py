"""DUAL's acting step stays on the policy's device (issue 40, item 4).

A CUDA graph cannot capture a host-to-device copy, and under ``torch.compile`` the cached
tensors of the one-step fast path (``VersionedCache``) are recomputed inside the graph at
every step: a tensor made on the host there broke the capture of the acting step on the
H200 (docs/benchmarks.md). Without a GPU here, the policy is moved to the ``meta``
device, where every op that makes or reads a host tensor shows: the step below records
each op whose output lies on the CPU, with the caches invalidated by the move (their
recomputation runs inside the step, as under compile) and the input checks that read a
value back switched off (as under compile)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

import torchrl_dual._utils
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import PlannerActor, TransitionModel, make_dual_policy

OBS, ACT = 3, 2


class _HostOps(TorchDispatchMode):
    """Records every op whose output is a CPU tensor."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: list[str] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for value in out if isinstance(out, (tuple, list)) else (out,):
            if isinstance(value, torch.Tensor) and value.device.type == "cpu":
                self.ops.append(str(func))
        return out


def _policy(num_steps: int, transition: str, uncertainty: str):
    torch.manual_seed(0)
    model = TrajectoryDiffusion(TrajectoryLayout(OBS, ACT, 4), num_steps=num_steps, hidden=16)
    model.normalizer.fit(torch.randn(64, OBS), torch.rand(64, ACT) * 2 - 1)
    actor = PlannerActor(model)
    if transition == "shared":
        transition_model = TransitionModel(model, frozen=False)
    else:
        transition_model = TransitionModel.frozen_copy(model)
    policy = make_dual_policy(
        actor, Bounded(-1.0, 1.0, shape=(ACT,)), transition_model=transition_model,
        uncertainty=uncertainty,
    )  # fmt: skip
    if uncertainty == "laplace":
        policy[0].fit_laplace([TensorDict(observation=torch.randn(64, OBS), batch_size=[64])])
    return policy


def _step(batch: int, device: str) -> TensorDict:
    observation = torch.randn(batch, OBS)
    return TensorDict(
        observation=observation,
        previous_observation=observation + 0.1,
        previous_action=torch.zeros(batch, ACT),
        previous_valid=torch.ones(batch, 1, dtype=torch.bool),
        batch_size=[batch],
    ).to(device)


@pytest.mark.parametrize(
    "num_steps, transition, uncertainty",
    [(1, "frozen-copy", "laplace"), (1, "shared", "laplace"), (4, "frozen-copy", "laplace"),
     (1, "frozen-copy", "latent")],
    ids=["one-step-paired", "one-step-shared", "four-step", "latent"],
)  # fmt: skip
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_an_acting_step_makes_no_host_tensor(num_steps, transition, uncertainty, mode, monkeypatch):
    # the input checks that read a value back are skipped under compile, as here
    monkeypatch.setattr(torchrl_dual._utils, "host_reads_allowed", lambda: False)
    policy = _policy(num_steps, transition, uncertainty).to("meta")
    step, recorder = _step(2, "meta"), _HostOps()
    with torch.no_grad(), set_exploration_type(mode), recorder:
        out = policy(step)
    assert out["action"].device.type == "meta"
    assert recorder.ops == []


def test_the_action_bounds_follow_the_policy_to_its_device_and_stay_out_of_its_state():
    policy = _policy(1, "frozen-copy", "laplace")
    keys = set(policy.state_dict())
    assert not any("action_low" in k or "action_high" in k for k in keys)
    moved = policy.to("meta")
    assert moved[0].action_low.device.type == "meta"
    assert moved[0].action_high.device.type == "meta"
    assert set(moved.state_dict()) == keys
