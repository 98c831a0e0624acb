"""Env steps per second of the recipe's collectors against the number of workers.

For each env (PointMaze U-maze as the recipe builds it, Gymnasium's MuJoCo Hopper-v5 via
TorchRL's ``GymEnv``; both with :class:`~torchrl_dual.transforms.PreviousTransition`) and
each policy (``random``: TorchRL's ``RandomPolicy``; ``mlp``: a stand-in for DUAL's acting
cost, an ensemble of 5 MLPs of width 256 whose mean is the action), runs
``collector=single`` and ``multi_sync`` / ``multi_async`` / ``ray`` at each worker count
with the collectors the recipe builds (TorchRL's ``Collector``, ``MultiSyncCollector``,
``MultiAsyncCollector``, and ``RayCollector`` with one-env remote collectors, asynchronous
as the recipe's ``collector=ray`` default) and prints env steps per second of wall-clock
time, and the ratio to ``single`` measured in the same run. The first batch of every
collector (worker start-up) is left out of the timing; the policy's weights are pushed
after every batch, as the recipe does after every update block (there are no updates
here: this is collection alone). ``ray`` runs on one Ray runtime for the whole script:
the cluster at ``--ray-address``, else (as the recipe's ``collector.address=null``) a
running cluster or a new local runtime; its start-up is not timed.

Example:
    python -m benchmarks.speed.collectors --envs pointmaze hopper --workers 1 2 --frames 4000
    python -m benchmarks.speed.collectors --collectors single ray --ray-address auto
"""

from __future__ import annotations

import argparse
import functools
import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import (
    BaseCollector,
    Collector,
    MultiAsyncCollector,
    MultiSyncCollector,
    RandomPolicy,
)
from torchrl.envs import DoubleToFloat, EnvBase, GymEnv
from torchrl.envs.utils import ExplorationType

from benchmarks.learning.backends import connect_ray
from benchmarks.provenance import write_json
from torchrl_dual.envs import make_pointmaze_env
from torchrl_dual.recipe.settings.o2o import INSTALL_RAY, ray_installed
from torchrl_dual.transforms import PreviousTransition

RAY = ray_installed()


def make_env(name: str) -> EnvBase:
    """The benchmark's env ``name`` with ``PreviousTransition`` (module level: picklable)."""
    if name == "pointmaze":
        env = make_pointmaze_env("umaze", max_episode_steps=300, seed=0)
    elif name == "hopper":
        env = GymEnv("Hopper-v5").append_transform(DoubleToFloat())
    else:
        raise ValueError(f"unknown env {name!r}; choose pointmaze or hopper")
    return env.append_transform(PreviousTransition())


class EnsembleMean(nn.Module):
    """``members`` MLPs of width ``width``; the action is the tanh of their mean."""

    def __init__(self, obs_dim: int, action_dim: int, members: int = 5, width: int = 256):
        super().__init__()
        self.members = nn.ModuleList(
            nn.Sequential(
                nn.Linear(obs_dim, width),
                nn.ReLU(),
                nn.Linear(width, width),
                nn.ReLU(),
                nn.Linear(width, action_dim),
            )
            for _ in range(members)
        )

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return torch.stack([m(observation) for m in self.members]).mean(0).tanh()


def make_policy(kind: str, env: EnvBase) -> nn.Module:
    if kind == "random":
        return RandomPolicy(env.action_spec)
    module = EnsembleMean(env.observation_spec["observation"].shape[-1], env.action_spec.shape[-1])
    return TensorDictModule(module, in_keys=["observation"], out_keys=["action"])


def make_ray_collector(
    factory: Callable[[], EnvBase], policy: nn.Module, workers: int, common: dict
) -> BaseCollector:
    """TorchRL's ``RayCollector``, as the recipe's ``collector=ray`` builds it: ``workers``
    remote collectors of one CPU, one env each, asynchronous."""
    from torchrl.collectors.distributed import RayCollector  # imports ray

    kwargs = {"auto_register_policy_transforms": common["auto_register_policy_transforms"]}
    return RayCollector(
        [factory] * workers,
        policy,
        frames_per_batch=common["frames_per_batch"],
        total_frames=common["total_frames"],
        exploration_type=common["exploration_type"],
        device="cpu",
        collector_kwargs=kwargs,
        remote_configs={"num_cpus": 1},
    )


def steps_per_second(
    env_name: str, policy_kind: str, collector: str, workers: int, frames: int, batch: int
) -> float:
    """Env steps per second after the first batch."""
    factory = functools.partial(make_env, env_name)
    probe = factory()
    policy = make_policy(policy_kind, probe)
    common = {
        "frames_per_batch": batch,
        "total_frames": frames + batch,
        "exploration_type": ExplorationType.RANDOM,
        "auto_register_policy_transforms": False,
    }
    if collector == "single":
        probe.set_seed(1)
        runner = Collector(probe, policy, **common)
    else:
        probe.close()
        if collector == "ray":
            runner = make_ray_collector(factory, policy, workers, common)
        else:
            cls = MultiSyncCollector if collector == "multi_sync" else MultiAsyncCollector
            runner = cls([factory] * workers, policy, num_threads=1, **common)
        runner.set_seed(1)
    push = not isinstance(runner, Collector) and isinstance(policy, TensorDictModule)
    try:
        start, counted = None, 0
        for data in runner:
            if start is None:  # worker start-up and the first batch are not timed
                start = time.perf_counter()
                continue
            counted += data.numel()
            if push:
                runner.update_policy_weights_(TensorDict.from_module(policy).data)
        return counted / (time.perf_counter() - start)
    finally:
        runner.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--envs", nargs="+", default=["pointmaze", "hopper"])
    parser.add_argument("--policies", nargs="+", default=["random", "mlp"])
    parser.add_argument("--workers", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--frames", type=int, default=4000, help="timed frames per setting")
    parser.add_argument("--batch", type=int, default=200, help="frames per collector batch")
    parser.add_argument(
        "--collectors",
        nargs="+",
        choices=["multi_sync", "multi_async", "ray"],
        default=["multi_sync", "multi_async", *(["ray"] if RAY else [])],
        help="compared with single at each worker count (default: all, ray if installed)",
    )
    parser.add_argument(
        "--ray-address",
        help="ray: the cluster's address (default: a running cluster, else a local runtime)",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the figures here")
    args = parser.parse_args()
    if "ray" in args.collectors and not RAY:
        parser.error(f"--collectors ray needs Ray, which is not installed: {INSTALL_RAY}")
    torch.set_num_threads(1)
    runtime = ray_runtime(args.ray_address) if "ray" in args.collectors else nullcontext()
    with runtime:
        run_settings(args)


@contextmanager
def ray_runtime(address: str | None) -> Iterator[None]:
    """Connected to Ray for the ``with`` block (``benchmarks.learning.backends``'s
    ``connect_ray``); a connection the block made is ended after it (a local runtime stops,
    a cluster keeps running), one made before it is left as it is."""
    import ray

    started = not ray.is_initialized()
    connect_ray(address)
    try:
        yield
    finally:
        if started:
            ray.shutdown()


def run_settings(args: argparse.Namespace) -> None:
    """Times every (env, policy, collector, workers) of ``args`` and prints the table."""
    print("| env | policy | collector | workers | env steps / s | vs single |", flush=True)
    print("|---|---|---|---:|---:|---:|", flush=True)
    results = []
    for env_name in args.envs:
        for policy in args.policies:
            settings = [("single", 1)]
            settings += [(c, w) for c in args.collectors for w in args.workers]
            single = None
            for collector, workers in settings:
                rate = steps_per_second(
                    env_name, policy, collector, workers, args.frames, args.batch
                )
                single = rate if single is None else single
                results.append((env_name, policy, collector, workers, rate))
                print(
                    f"| {env_name} | {policy} | {collector} | {workers} | {rate:.0f} "
                    f"| {rate / single:.2f} |",
                    flush=True,
                )
    print(f"load average at the end: {os.getloadavg()[0]:.1f} (2 cores)")
    if args.json is not None:
        keys = ("env", "policy", "collector", "workers", "steps_per_second")
        write_json(args.json, [dict(zip(keys, r, strict=True)) for r in results])


if __name__ == "__main__":
    main()
