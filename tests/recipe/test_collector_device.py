"""``collector.device``: where the acting policy runs, apart from the update ``device``
(issue 30 item 3). This machine has no GPU, so the two devices cannot differ here; what is
checked is the config, the default (the run's device), that one device shares the learner's
policy (nothing pushed), and that a collector acting with its own copy, as TorchRL's
``Collector`` makes one on another device, gets the learner's weights and buffers from
:func:`push_to_single`."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import GymEnv

from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked
from torchrl_dual.recipe.o2o.collectors import collector_device, push_to_single

TINY = ("budget=smoke", "env=frozenlake", "progress=false")


class _Linear(nn.Module):
    """A policy network with a buffer (as DUAL's Laplace draws are buffers)."""

    def __init__(self) -> None:
        super().__init__()
        self.net = nn.Linear(3, 1)
        self.register_buffer("offset", torch.zeros(1))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return (self.net(observation) + self.offset).clamp(-2.0, 2.0)


def _policy() -> TensorDictModule:
    return TensorDictModule(_Linear(), in_keys=["observation"], out_keys=["action"])


def _collector(policy: nn.Module) -> Collector:
    return Collector(
        GymEnv("Pendulum-v1"),
        policy,
        frames_per_batch=4,
        total_frames=-1,
        device="cpu",
        auto_register_policy_transforms=False,
    )


def test_collector_device_defaults_to_the_run_device_and_is_checked(tmp_path):
    cfg = compose_checked(CONFIG_DIR, [*TINY, f"output_dir={tmp_path}"])
    assert cfg.collector.device is None and collector_device(cfg) == torch.device("cpu")
    cfg = compose_checked(CONFIG_DIR, [*TINY, f"output_dir={tmp_path}", "collector.device=cpu"])
    assert collector_device(cfg) == torch.device("cpu")
    for value, problem in [
        ("banana", "not a torch device; use cpu, cuda or cuda:N"),
        ("mps", "the recipe runs on cpu or cuda"),
    ]:
        with pytest.raises(ConfigError, match=f"^collector.device={value}: {problem}$"):
            compose_checked(
                CONFIG_DIR, [*TINY, f"output_dir={tmp_path}", f"collector.device={value}"]
            )
    if not torch.cuda.is_available():
        with pytest.raises(
            ConfigError,
            match="^collector.device=cuda: CUDA is not available here; use collector.device=cpu$",
        ):
            compose_checked(CONFIG_DIR, [*TINY, f"output_dir={tmp_path}", "collector.device=cuda"])


def test_on_one_device_the_collector_acts_with_the_learner_s_policy_and_nothing_is_pushed():
    policy = _policy()
    collector = _collector(policy)
    try:
        assert collector.policy is policy
        calls = []
        collector.update_policy_weights_ = lambda *a, **k: calls.append(a)
        push_to_single(collector, policy)
        assert not calls
    finally:
        collector.shutdown()


def test_a_collector_s_own_copy_gets_the_learner_s_weights_and_buffers_from_the_push():
    learner = _policy()
    collector = _collector(copy.deepcopy(learner))  # a copy, as on another device
    try:
        acting = collector.policy
        assert acting is not learner
        with torch.no_grad():
            learner.module.net.weight.add_(1.0)
            learner.module.offset = torch.full((1,), 0.5)  # replaced, not updated in place
        assert not torch.equal(acting.module.offset, learner.module.offset)
        push_to_single(collector, learner)
        torch.testing.assert_close(acting.module.net.weight, learner.module.net.weight)
        torch.testing.assert_close(acting.module.offset, learner.module.offset)
        batch = next(iter(collector))
        expected = learner(batch.select("observation").clone())["action"]
        torch.testing.assert_close(batch["action"], expected)
    finally:
        collector.shutdown()


def test_ray_s_remote_collectors_act_on_the_cpu_only(tmp_path):
    pytest.importorskip("ray")
    with pytest.raises(
        ConfigError,
        match="^collector.device=cuda: collector=ray's remote collectors act on the CPUs of "
        "the Ray nodes: use null or cpu$",
    ):
        compose_checked(
            CONFIG_DIR,
            [*TINY, f"output_dir={tmp_path}", "collector=ray", "collector.device=cuda"],
        )
