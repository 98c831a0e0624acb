"""The recipe end to end on one machine, and ``budget=paper`` on AntMaze projected from
that run's own figures only (issue 40, item 4; docs/benchmarks.md, "DUAL on a GPU").

    python -m benchmarks.speed.e2e_probe --device cuda --cudagraphs --json probe.json
    python -m benchmarks.speed.e2e_probe --scale tiny --json probe.json   # a CPU check, seconds

Writes a stand-in for ``D4RL/antmaze/umaze-v1`` (random actions in the data set's maze:
``torchrl_dual.data.minari_standins``; nothing is downloaded) into ``--data``, then runs
``python -m torchrl_dual.recipe env=antmaze budget=paper`` with every count cut to
``--scale`` (``probe``: about 3 minutes on a current GPU) and the paper's sizes otherwise
(256 x 2 networks, batch 256, 100 evaluation episodes; ``budget.frames_per_batch`` the
nearest multiple of ``--num-envs`` to the paper's 1000), reads the stage times of its
``summary.json`` and turns them into rates: planner, distillation and offline actor-critic
updates per second, the posterior fit per 1000 transitions, one evaluation of
``budget.eval_episodes`` episodes, and one online frame (collection, acting and its
``online.utd_ratio`` updates; the probe's online phase has no refit and no evaluation,
which are counted on their own).

:func:`benchmarks.speed.gpu_projection.project_from_probe` then gives the hours of one
``budget=paper`` run from these figures only, each labelled with the machine, the date and
the command that measured it.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.provenance import write_json
from benchmarks.speed.gpu_projection import PAPER, project_from_probe

REPO = Path(__file__).resolve().parents[2]
DATASET_ID = "D4RL/antmaze/umaze-v1"

SCALES: dict[str, dict] = {
    # about 3 minutes on one H100/H200 (planner and distillation at the GPU rates of 12-04)
    "probe": {
        "planner_updates": 4000, "distill_updates": 200, "offline_updates": 4000,
        "online_batches": 4, "eval_episodes": 100, "episodes": 40, "steps": 500,
    },
    # seconds on a CPU: checks that the probe runs and reads its run right (tests)
    "tiny": {
        "planner_updates": 20, "distill_updates": 4, "offline_updates": 20,
        "online_batches": 2, "eval_episodes": 2, "episodes": 4, "steps": 40,
        "frames_per_batch": 16, "max_episode_steps": 20,
    },
}  # fmt: skip
"""Counts of each scale; the rest is ``budget=paper``'s."""


def overrides(scale: dict, num_envs: int) -> list[str]:
    """The recipe overrides of one probe run (``budget=paper`` with the counts cut)."""
    per_batch = scale.get("frames_per_batch", PAPER["frames_per_batch"])
    per_batch = max(num_envs, round(per_batch / num_envs) * num_envs)
    frames = scale["online_batches"] * per_batch
    distill = ",".join([str(scale["distill_updates"])] * len(PAPER["distill_updates"]))
    updates = scale["offline_updates"]
    result = [
        "env=antmaze", "algo=dual", "budget=paper", "progress=false",
        f"budget.planner_updates={scale['planner_updates']}",
        f"budget.distill_updates=[{distill}]",
        f"budget.offline_updates={updates}",
        f"budget.online_frames={frames}",
        f"budget.frames_per_batch={per_batch}",
        f"budget.eval_episodes={scale['eval_episodes']}",
        # no evaluation, refit or checkpoint inside the online phase: each is timed on its own
        f"budget.eval_every={frames * 10}",
        f"budget.laplace_refit_every={frames * 10}",
        f"budget.checkpoint_every={frames * 10}",
        f"budget.offline_checkpoint_every={updates * 10}",
        f"collector.num_envs={num_envs}",
    ]  # fmt: skip
    if "max_episode_steps" in scale:
        result.append(f"env.max_episode_steps={scale['max_episode_steps']}")
    return result


def write_data(path: Path, scale: dict) -> int:
    """The stand-in data set, once per ``path`` and scale; returns its transitions."""
    marker = path / f".standin_{scale['episodes']}x{scale['steps']}"
    if marker.exists():
        return int(marker.read_text())
    from torchrl_dual.data.minari_standins import write_standin_dataset

    before = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(path)  # where Minari writes
    try:
        dataset = write_standin_dataset(DATASET_ID, scale["episodes"], scale["steps"])
    finally:
        if before is None:
            del os.environ["MINARI_DATASETS_PATH"]
        else:
            os.environ["MINARI_DATASETS_PATH"] = before
    marker.write_text(str(dataset.total_steps))
    return int(dataset.total_steps)


def rates(summary: dict, transitions: int) -> dict[str, float]:
    """Per-second and per-unit figures from a probe run's ``summary.json``."""
    budget, stages = summary["config"]["budget"], summary["stage_seconds"]
    online = summary["config"]["online"]
    frames = int(budget["online_frames"])
    return {
        "planner_updates_per_s": budget["planner_updates"] / stages["planner"],
        "distill_updates_per_s": sum(budget["distill_updates"]) / stages["distillation"],
        "offline_updates_per_s": budget["offline_updates"] / stages["actor_critic"],
        "laplace_s_per_1k_transitions": stages["laplace"] / (transitions / 1000),
        "evaluation_s": stages["offline_eval"],
        "evaluation_episodes": int(budget["eval_episodes"]),
        "online_s_per_frame": stages["online"] / frames,
        "online_utd_ratio": float(online["utd_ratio"]),
        "online_frames": frames,
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--cudagraphs", action="store_true", help="compile.cudagraphs=true")
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--scale", choices=sorted(SCALES), default="probe")
    parser.add_argument("--data", type=Path, default=None, help="MINARI_DATASETS_PATH to use")
    parser.add_argument("--out", type=Path, default=None, help="the run's output_dir")
    parser.add_argument("--timeout", type=float, default=900.0)
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("overrides", nargs="*", help="more recipe overrides (key=value)")
    args = parser.parse_args(argv)
    scale = SCALES[args.scale]
    with tempfile.TemporaryDirectory() as tmp:
        data = args.data or Path(tmp) / "minari"
        out = args.out or Path(tmp) / "run"
        data.mkdir(parents=True, exist_ok=True)
        transitions = write_data(data, scale)
        command = [
            sys.executable, "-m", "torchrl_dual.recipe", *overrides(scale, args.num_envs),
            f"device={args.device}", f"output_dir={out}", *args.overrides,
        ]  # fmt: skip
        if args.cudagraphs:
            command.append("compile.cudagraphs=true")
        env = {**os.environ, "MINARI_DATASETS_PATH": str(data)}
        begin = time.perf_counter()
        done = subprocess.run(command, cwd=REPO, env=env, timeout=args.timeout)
        wall = time.perf_counter() - begin
        if done.returncode != 0:
            raise SystemExit(f"error: the probe run failed (exit {done.returncode}): {command}")
        summary = json.loads((out / "summary.json").read_text())
    measured = {
        "machine": f"{platform.node()} ({platform.processor() or platform.machine()}), "
        f"device={args.device}",
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        "command": "python -m benchmarks.speed.e2e_probe " + " ".join(argv or sys.argv[1:]),
    }
    report = {
        "measured": measured,
        "run_wall_seconds": wall,
        "stage_seconds": summary["stage_seconds"],
        "rates": rates(summary, transitions),
        "overrides": command[3:],
    }
    report["paper_hours"] = project_from_probe(report)
    print(f"measured on {measured['machine']}, {measured['date']}")
    for name, value in report["rates"].items():
        print(f"  {name}: {value:.4g}")
    hours = {k: round(v, 3) for k, v in report["paper_hours"].items() if k != "inputs"}
    print(f"budget=paper on AntMaze, projected from these figures only (hours): {hours}")
    if args.json is not None:
        write_json(args.json, report, indent=2)
    return report


if __name__ == "__main__":
    main()
