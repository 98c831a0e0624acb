"""Env steps per second of ``collector=single`` against ``collector.num_envs`` (issue 40).

For each env (PointMaze U-maze, and MuJoCo Hopper as the locomotion Minari family builds
it, on a stand-in data set written to a temporary ``MINARI_DATASETS_PATH``), builds the
recipe's collection env at each ``collector.num_envs`` (``make_collection_env``: the
online env itself at 1, else that many copies stepped as one batch) and TorchRL's
``Collector`` over it, as ``collector=single`` does, acting with DUAL's exploration policy
(``dual_m5`` of ``latency_candidates.py``: the one-step planner actor, Laplace ensemble
M = 5, shift-aware noise, at the env's observation and action sizes). Every collector
collects ``--batch`` frames per batch (env steps over all its envs); after one batch
each (start-up, left out), the rounds alternate between the env counts, each timing
``--frames`` frames of wall-clock time, so load from other processes affects every count
alike. Prints the median env steps/s per count and the median over rounds of its ratio
to ``num_envs=1`` in the same round. Collection alone: no updates, no weight pushes.

Example:
    python -m benchmarks.speed.collection_speed                       # PointMaze and Hopper, 1 4 16
    python -m benchmarks.speed.collection_speed --envs pointmaze --rounds 5 --json speed.json
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import torch
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType

from benchmarks.provenance import write_json
from benchmarks.speed.latency_candidates import Config, build_dual_m5
from torchrl_dual.recipe import CONFIG_DIR, RecipeSettings, compose_checked
from torchrl_dual.recipe.kits import build as env_kits

ENVS = {
    "pointmaze": ("env=pointmaze_umaze", None),
    "hopper": ("env=hopper", "mujoco/hopper/medium-v0"),
}
"""``--envs`` name -> (the recipe's env override, the Minari stand-in data set it reads)."""


def collectors(
    name: str, counts: list[int], batch: int, workdir: Path
) -> tuple[dict[int, Collector], int]:
    """``num_envs -> Collector`` on the recipe's collection env of ``name``, all acting
    with one DUAL exploration policy; and the env's time limit."""
    override, dataset_id = ENVS[name]
    data = None
    if dataset_id is not None:
        from torchrl_dual.data import write_standin_dataset

        write_standin_dataset(dataset_id, num_episodes=8, steps=100)
    policy = None
    out = {}
    for count in counts:
        cfg = compose_checked(
            CONFIG_DIR,
            [
                override,
                "budget=smoke",
                f"budget.frames_per_batch={batch}",
                f"collector.num_envs={count}",
                f"output_dir={workdir / 'run'}",
                f"data_cache_dir={workdir / 'data'}",
            ],
        )
        settings = RecipeSettings.of(cfg)
        if dataset_id is not None and data is None:
            data = env_kits.make_offline_dataset(settings)  # the observation normalizer's
        env = env_kits.make_train_env(settings, data)
        if policy is None:
            obs_dim = env.observation_spec["observation"].shape[-1]
            policy = build_dual_m5(Config(obs_dim=obs_dim, action_dim=env.action_spec.shape[-1]))
        env = env_kits.make_collection_env(settings, data, env)
        env.set_seed(cfg.seed + 1)
        out[count] = Collector(
            env,
            policy,
            frames_per_batch=batch,
            total_frames=-1,
            exploration_type=ExplorationType.RANDOM,
            auto_register_policy_transforms=False,
        )
    return out, cfg.env.max_episode_steps


def time_frames(batches, frames: int) -> float:
    """Env steps per second over at least ``frames`` frames of ``batches``."""
    start, done = time.perf_counter(), 0
    while done < frames:
        done += next(batches).numel()
    return done / (time.perf_counter() - start)


def measure(name: str, args: argparse.Namespace, workdir: Path) -> dict:
    made, time_limit = collectors(name, args.num_envs, args.batch, workdir)
    iterators = {count: iter(collector) for count, collector in made.items()}
    try:
        for batches in iterators.values():
            next(batches)  # start-up
        rates: dict[int, list[float]] = {count: [] for count in made}
        for _ in range(args.rounds):
            for count, batches in iterators.items():
                rates[count].append(time_frames(batches, args.frames))
    finally:
        for collector in made.values():
            collector.shutdown()
    base = args.num_envs[0]
    rows = {}
    for count, values in rates.items():
        ratios = [v / b for v, b in zip(values, rates[base], strict=True)]
        rows[count] = {
            "steps_per_s": statistics.median(values),
            "steps_per_s_all": values,
            f"ratio_to_{base}": statistics.median(ratios),
        }
    return {"max_episode_steps": time_limit, "num_envs": rows}


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--envs", nargs="+", choices=sorted(ENVS), default=list(ENVS))
    parser.add_argument("--num-envs", nargs="+", type=int, default=[1, 4, 16])
    parser.add_argument("--batch", type=int, default=160, help="frames per collected batch")
    parser.add_argument("--frames", type=int, default=1600, help="timed frames per round")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    bad = [n for n in args.num_envs if n < 1 or args.batch % n]
    if bad:
        parser.error(f"--batch {args.batch} must be a multiple of every --num-envs ({bad})")
    torch.set_num_threads(args.threads)
    machine = {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "threads": args.threads,
        "load_average": os.getloadavg(),
    }
    print(
        f"{machine['cpu']}, {machine['cores']} cores, {args.threads} torch thread(s), load "
        f"{machine['load_average'][0]:.2f} | batch {args.batch} frames, {args.rounds} rounds "
        f"of {args.frames} frames per count"
    )
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        previous = os.environ.get("MINARI_DATASETS_PATH")
        os.environ["MINARI_DATASETS_PATH"] = str(Path(tmp) / "minari")
        try:
            for name in args.envs:
                results[name] = measure(name, args, Path(tmp) / name)
        finally:
            if previous is None:
                os.environ.pop("MINARI_DATASETS_PATH")
            else:
                os.environ["MINARI_DATASETS_PATH"] = previous
    base = args.num_envs[0]
    print(
        f"| env | collector.num_envs | env steps/s (median) "
        f"| / num_envs={base} (median of per-round ratios) |"
    )
    print("|---|---|---|---|")
    for name, result in results.items():
        for count, row in result["num_envs"].items():
            print(
                f"| {name} | {count} | {row['steps_per_s']:.0f} | {row[f'ratio_to_{base}']:.2f}x |"
            )
    out = {"machine": machine, "args": {k: str(v) for k, v in vars(args).items()}, **results}
    if args.json is not None:
        write_json(args.json, out, indent=2)
    return out


if __name__ == "__main__":
    main()
