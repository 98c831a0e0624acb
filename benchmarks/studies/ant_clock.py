"""What the ant's clock changes: AntMaze at D4RL's step count against D4RL's simulated time.

    python -m benchmarks.studies.ant_clock --json benchmarks/results/ant_clock.json   # ~3 min

D4RL's ant steps 0.1 s (timestep 0.02 x frame skip 5), Gymnasium-Robotics' ant, which
Minari's data were recorded with, 0.05 s (0.01 x 5): D4RL's 700 umaze steps are 70
simulated seconds there, 35 s here. ``env.horizon_seconds=d4rl`` gives D4RL's 70 s (1400
steps here). On a fixture (the stand-in ``D4RL/antmaze/umaze-v1``, random actions:
``torchrl_dual.data.minari_standins``) this measures, for the default (``null``: 700
steps) and ``d4rl``:

* the kit's evaluation env under a uniform random policy (``--episodes`` episodes): steps
  and simulated seconds per episode, success rate, the farthest the torso gets from its
  start, wall seconds per episode;
* a ``budget=smoke`` recipe run of ``--algo`` on that data (seed 0, one thread): its final
  score, online episodes begun, and wall seconds.

A fixture of random actions cannot show what the clock does to learning on the published
data; it shows what it changes in the task and in the cost of a run.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.provenance import write_json

DATASET = "D4RL/antmaze/umaze-v1"
SETTINGS = {"default (700 steps)": (), "d4rl (70 s)": ("env.horizon_seconds=d4rl",)}


def _compose(out: Path, *overrides: str):
    from torchrl_dual.recipe import CONFIG_DIR, compose_checked

    return compose_checked(
        CONFIG_DIR,
        [f"output_dir={out}", "budget=smoke", "progress=false", "env=antmaze", *overrides],
    )


def random_episodes(cfg, episodes: int, seed: int = 0) -> dict:
    """``episodes`` uniform-random episodes in the kit's evaluation env of ``cfg``."""
    from torchrl_dual.recipe import RecipeSettings
    from torchrl_dual.recipe.kits import build
    from torchrl_dual.recipe.kits.minari_families import minari_gym_env

    settings = RecipeSettings.of(cfg)
    data = build.make_offline_dataset(settings)
    env = minari_gym_env(settings, data, eval_env=True, shifted=False)
    dt = float(env.unwrapped.ant_env.dt)
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(episodes):
        env.reset(seed=seed + k)
        start = env.unwrapped.ant_env.data.qpos[:2].copy()
        farthest, steps, success, begin = 0.0, 0, False, time.perf_counter()
        done = False
        while not done:
            action = rng.uniform(env.action_space.low, env.action_space.high)
            _, _, terminated, truncated, info = env.step(action.astype(np.float32))
            xy = env.unwrapped.ant_env.data.qpos[:2]
            farthest = max(farthest, float(np.linalg.norm(xy - start)))
            steps, success, done = steps + 1, bool(info.get("success")), terminated or truncated
        rows.append((steps, success, farthest, time.perf_counter() - begin))
    env.close()
    steps, success, farthest, wall = (list(column) for column in zip(*rows, strict=True))
    return {
        "time_limit_steps": env.spec.max_episode_steps,
        "step_seconds": dt,
        "simulated_seconds": statistics.fmean(steps) * dt,
        "steps_mean": statistics.fmean(steps),
        "success_rate": statistics.fmean(success),
        "farthest_m_mean": statistics.fmean(farthest),
        "farthest_m_max": max(farthest),
        "wall_s_per_episode": statistics.median(wall),
    }


def smoke_run(out: Path, algo: str, *overrides: str) -> dict:
    """A ``budget=smoke`` run of ``algo`` (seed 0, one thread) under ``overrides``."""
    from torchrl_dual.recipe import run

    begin = time.perf_counter()
    result = run(_compose(out, f"algo={algo}", "num_threads=1", "seed=0", *overrides))
    final = result.history[-1]
    return {
        "final_score": final["normalized_score"],
        "offline_score": result.history[0]["normalized_score"],
        "wall_seconds": time.perf_counter() - begin,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--algo", default="iql")
    parser.add_argument("--data-episodes", type=int, default=20, help="stand-in episodes")
    parser.add_argument("--data-steps", type=int, default=200, help="stand-in steps each")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    from torchrl_dual.data.minari_standins import write_standin_dataset

    results: dict = {"args": {k: str(v) for k, v in vars(args).items()}, "settings": {}}
    with tempfile.TemporaryDirectory() as tmp:
        previous = os.environ.get("MINARI_DATASETS_PATH")
        os.environ["MINARI_DATASETS_PATH"] = str(Path(tmp) / "minari")
        try:
            write_standin_dataset(DATASET, args.data_episodes, args.data_steps)
            for name, overrides in SETTINGS.items():
                out = Path(tmp) / name.split()[0]
                cfg = _compose(out / "env", *overrides)
                results["settings"][name] = {
                    "overrides": list(overrides),
                    "random_policy": random_episodes(cfg, args.episodes),
                    "smoke_run": smoke_run(out / "run", args.algo, *overrides),
                }
        finally:
            if previous is None:
                os.environ.pop("MINARI_DATASETS_PATH", None)
            else:
                os.environ["MINARI_DATASETS_PATH"] = previous
    print("| setting | time limit | simulated s | random: success | random: farthest m (mean / max) "
          f"| s per episode | smoke {args.algo}: final score | smoke wall s |")  # fmt: skip
    print("|---|---:|---:|---:|---|---:|---:|---:|")
    for name, row in results["settings"].items():
        r, s = row["random_policy"], row["smoke_run"]
        score = "nan" if math.isnan(s["final_score"]) else f"{s['final_score']:.1f}"
        print(
            f"| {name} | {r['time_limit_steps']} | {r['simulated_seconds']:.0f} "
            f"| {r['success_rate']:.2f} | {r['farthest_m_mean']:.2f} / {r['farthest_m_max']:.2f} "
            f"| {r['wall_s_per_episode']:.2f} | {score} | {s['wall_seconds']:.0f} |"
        )
    if args.json is not None:
        write_json(args.json, results, indent=1)
    return results


if __name__ == "__main__":
    main()
