"""A run killed with SIGKILL during its online phase and resumed ends bitwise as the same
run never interrupted (issue 31): same online transitions, evaluation history, weights,
optimizer states, counters and random state.

Three recipe runs of one config and seed, each in its own interpreter with one thread:

1. ``whole``: the run, uninterrupted;
2. ``killed``: the same run, sent ``SIGKILL`` (``kill -9``: no handler, no last save)
   ``--kill-delay`` seconds after it reports its first online evaluation at or past
   ``--kill-after`` frames, so it dies somewhere in the online loop, after a periodic
   checkpoint and before the end;
3. ``killed`` again with ``resume=true``, from whatever checkpoint the kill left.

It then compares the two final checkpoints with
:func:`torchrl_dual.checkpoint.state_differences` (everything but the stages' wall times
and the logger's paths) and prints what differs: nothing, when resume works.

Usage::

    python -m benchmarks.robustness.resume_kill                      # DUAL, budget=smoke, seed 0
    python -m benchmarks.robustness.resume_kill --algo iql --json out.json -- env=frozenlake
    python -m benchmarks.robustness.resume_kill --code ../old-checkout  # the recipe of another tree

Arguments after ``--`` are extra recipe overrides.
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import torch

from benchmarks.provenance import provenance, write_json
from torchrl_dual.checkpoint import state_differences

REPO = Path(__file__).resolve().parents[2]
WALL_CLOCK = ("stage_seconds", "stage_cpu_seconds", "logger")
"""What two runs of the same seed may differ in: the stages' times and the logger's paths."""
EVALUATION = re.compile(r"online @ (\d+) frames")


def recipe_command(out: Path, algo: str, budget: str, seed: int, extra: list[str]) -> list[str]:
    return [
        sys.executable,
        str(REPO / "recipes" / "o2o.py"),
        f"budget={budget}",
        f"algo={algo}",
        f"seed={seed}",
        "num_threads=1",
        "progress=false",
        f"output_dir={out}",
        *extra,
    ]


def run_to_end(command: list[str], env: dict[str, str]) -> float:
    """Runs ``command``; returns its wall seconds (raises with its output if it fails)."""
    start = time.perf_counter()
    proc = subprocess.run(command, capture_output=True, text=True, cwd=REPO, env=env)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed:\n{proc.stdout[-2000:]}{proc.stderr}")
    return time.perf_counter() - start


def run_and_kill(command: list[str], after_frames: int, delay: float, env: dict) -> dict:
    """Starts ``command`` and SIGKILLs it ``delay`` s after its first online evaluation at
    ``after_frames`` frames or more; returns what it printed up to the kill."""
    proc = subprocess.Popen(
        command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO, env=env
    )
    lines: list[str] = []
    killed_after: int | None = None
    for line in proc.stdout:
        lines.append(line.rstrip())
        match = EVALUATION.search(line)
        if match and int(match.group(1)) >= after_frames:
            killed_after = int(match.group(1))
            timer = threading.Timer(delay, os.kill, (proc.pid, signal.SIGKILL))
            timer.start()
            break
    if killed_after is None:
        proc.wait()
        raise RuntimeError(
            f"no online evaluation at >= {after_frames} frames:\n" + "\n".join(lines)
        )
    for line in proc.stdout:  # drain until the kill lands
        lines.append(line.rstrip())
    code = proc.wait()
    if code != -signal.SIGKILL:
        raise RuntimeError(f"the run ended (exit {code}) before the kill; raise --kill-after")
    return {"evaluated_at": killed_after, "exit_code": code, "last_line": lines[-1]}


def count_leaves(state: object) -> int:
    """The compared leaves of a checkpoint state (tensors, arrays, numbers, strings)."""
    if isinstance(state, dict) or hasattr(state, "batch_size"):
        items = state.items() if isinstance(state, dict) else state.items(True, True)
        return sum(count_leaves(v) for k, v in items if k not in WALL_CLOCK)
    if isinstance(state, list | tuple):
        return sum(count_leaves(v) for v in state)
    return 1


def final_state(out: Path) -> dict:
    payload = torch.load(out / "checkpoint.pt", map_location="cpu", weights_only=False)
    return payload["state"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--algo", default="dual")
    parser.add_argument("--budget", default="smoke")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--kill-after", type=int, default=200, help="online frames")
    parser.add_argument("--kill-delay", type=float, default=0.5, help="seconds")
    parser.add_argument("--out", type=Path, default=None, help="default: a temporary dir")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument(
        "--code", type=Path, default=None, help="run the recipe of this source tree (PYTHONPATH)"
    )
    parser.add_argument("overrides", nargs="*", help="extra recipe overrides (after --)")
    args = parser.parse_args()

    root = args.out or Path(tempfile.mkdtemp(prefix="resume_kill_"))
    whole, killed = root / "whole", root / "killed"
    command = lambda out, *more: recipe_command(  # noqa: E731
        out, args.algo, args.budget, args.seed, [*args.overrides, *more]
    )
    env = dict(os.environ)
    if args.code is not None:  # e.g. an older checkout, to see what it did
        env["PYTHONPATH"] = str(args.code.resolve())
    seconds = run_to_end(command(whole), env)
    kill = run_and_kill(command(killed), args.kill_after, args.kill_delay, env)
    at_kill = final_state(killed)
    run_to_end(command(killed, "resume=true"), env)
    a, b = final_state(whole), final_state(killed)
    differ = state_differences(a, b, ignore=WALL_CLOCK)
    code = provenance(args.code or REPO)  # the source tree the recipe ran from
    result = {
        "algo": args.algo,
        "budget": args.budget,
        "seed": args.seed,
        "overrides": args.overrides,
        "code": code["commit"] + ("+dirty" if code["dirty"] else ""),
        "killed_after_evaluation_at_frames": kill["evaluated_at"],
        "kill_delay_seconds": args.kill_delay,
        "checkpoint_frames_at_kill": at_kill["frames"],
        "final_frames": (a["frames"], b["frames"]),
        "entries_compared": count_leaves(a),
        "differences": differ,
        "whole_run_seconds": round(seconds, 1),
        "machine": f"{code['cpu']}, {os.cpu_count()} cores",
        "torch": torch.__version__,
        "date": time.strftime("%Y-%m-%d"),
    }
    print(
        f"{args.algo}, budget={args.budget}, seed {args.seed}: killed (SIGKILL) "
        f"{args.kill_delay} s after the evaluation at {kill['evaluated_at']} frames; the last "
        f"checkpoint then held {at_kill['frames']} frames; resumed to {b['frames']}."
    )
    print(
        f"{result['entries_compared']} checkpoint entries compared with the uninterrupted run: "
        + ("all bitwise equal" if not differ else f"{len(differ)} differ: {differ[:20]}")
    )
    if args.json:
        write_json(args.json, result, indent=2, tree=args.code or REPO)
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()
