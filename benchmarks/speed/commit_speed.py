"""The recipe's update speed at two commits, in one run: CPU milliseconds per offline
actor+critic update (the ``actor_critic`` stage of ``summary.json``), before / after.

Each side is a source tree: ``--before`` a git revision (exported with ``git archive``
into a temporary directory), ``--after`` another revision or, by default, this checkout.
Every round runs each algorithm once per side, alternating sides, as its own
``python recipes/o2o.py`` process with ``num_threads=1`` and the side's source first on
``PYTHONPATH``; the two sides thus share the machine's load of that moment, and the
ratio of their medians is the speed-up. A short budget keeps the planner, distillation
and online phase small; only the actor+critic stage is timed::

    python -m benchmarks.speed.commit_speed --before f1d0d69 --algos dual iql --updates 1000
    python -m benchmarks.speed.commit_speed --before f1d0d69 --after HEAD~3 --rounds 3 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from benchmarks.provenance import write_json

REPO = Path(__file__).resolve().parents[2]

SHORT_BUDGET = (
    "budget=default",
    "budget.dataset_transitions=20000",
    "budget.planner_updates=20",
    "budget.distill_updates=[5,5,5,5,5]",
    "budget.online_frames=500",
    "budget.frames_per_batch=500",
    "budget.eval_every=500",
    "budget.eval_episodes=1",
    "budget.checkpoint_every=500",
)
"""Everything but the actor+critic stage as short as the config allows."""


def export_tree(revision: str, into: Path) -> Path:
    """The files of ``revision`` under ``into`` (``git archive``; no worktree is left)."""
    into.mkdir(parents=True)
    archive = into.with_suffix(".tar")
    subprocess.run(
        ["git", "archive", "--format=tar", "-o", str(archive), revision],
        cwd=REPO,
        check=True,
    )
    with tarfile.open(archive) as tar:
        tar.extractall(into, filter="data")
    archive.unlink()
    return into


def ms_per_update(tree: Path, algo: str, updates: int, work: Path, tag: str) -> float:
    """One recipe run from ``tree``; its actor+critic stage's CPU ms per update."""
    out = work / "runs" / tag
    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        str(tree / "recipes" / "o2o.py"),
        f"algo={algo}",
        *SHORT_BUDGET,
        f"budget.offline_updates={updates}",
        "seed=0",
        "num_threads=1",
        "progress=false",
        f"data_cache_dir={work / ('data-' + tree.name)}",
        f"output_dir={out}",
    ]
    proc = subprocess.run(cmd, env=env, cwd=work, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{tag} failed:\n{proc.stderr[-2000:]}")
    summary = json.loads((out / "summary.json").read_text())
    return 1000.0 * summary["stage_cpu_seconds"]["actor_critic"] / updates


def imported_from(tree: Path, cwd: Path) -> Path:
    """Where ``import torchrl_dual`` resolves with ``tree`` first on ``PYTHONPATH`` (run
    from ``cwd``, which Python puts first on the path)."""
    code = "import torchrl_dual, pathlib; print(pathlib.Path(torchrl_dual.__file__).parent)"
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, cwd=cwd, capture_output=True, text=True
    )
    return Path(out.stdout.strip()).parent


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="git revision of the baseline")
    parser.add_argument("--after", help="git revision to compare (default: this checkout)")
    parser.add_argument("--algos", nargs="+", default=["dual", "iql"])
    parser.add_argument("--updates", type=int, default=1000, help="timed updates per run")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write the measurements here")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="commit_speed_") as tmp:
        work = Path(tmp)
        trees = {"before": export_tree(args.before, work / "before")}
        trees["after"] = export_tree(args.after, work / "after") if args.after else REPO
        for side, tree in trees.items():
            if imported_from(tree, work).resolve() != tree.resolve():
                raise RuntimeError(f"{side}: torchrl_dual is not imported from {tree}")
        times: dict[str, dict[str, list[float]]] = {
            a: {"before": [], "after": []} for a in args.algos
        }
        for round_ in range(args.rounds):
            for algo in args.algos:
                sides = ("before", "after") if round_ % 2 == 0 else ("after", "before")
                for side in sides:
                    ms = ms_per_update(
                        trees[side], algo, args.updates, work, f"{side}-{algo}-r{round_}"
                    )
                    times[algo][side].append(ms)
                    print(f"round {round_} {algo:6s} {side:6s} {ms:7.2f} ms/update", flush=True)
    print(
        f"\n{args.updates} actor+critic updates per run, batch and networks of budget=default, "
        "1 thread; CPU ms per update, median over rounds"
    )
    print(f"{'algo':8s} {'before':>8s} {'after':>8s} {'speed-up (ratio of medians)':>9s}")
    rows = {}
    for algo, sides in times.items():
        before, after = statistics.median(sides["before"]), statistics.median(sides["after"])
        rows[algo] = {"before_ms": before, "after_ms": after, "speedup": before / after, **sides}
        print(f"{algo:8s} {before:8.2f} {after:8.2f} {before / after:8.2f}x")
    if args.json:
        meta = {
            "before": args.before,
            "after": args.after or "working tree",
            "updates": args.updates,
        }
        write_json(args.json, {**meta, "algos": rows}, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
