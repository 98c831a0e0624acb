"""How long the command line takes to report a bad config value, next to the imports it
avoids (issue 28): the recipe's config check imports neither torch nor TorchRL.

Each command runs ``--repeats`` times in a fresh interpreter, alternating, and the median
wall time of each is printed with its ratio to the bare interpreter's start. The commands:

* ``bad value``: ``python -m torchrl_dual.recipe budget.online_frames=-5`` (exit 2, one
  ``error:`` line; the check this script measures);
* ``python``: ``python -c pass``, the floor;
* ``import torch``, ``import torchrl``: what the check used to pay for before reporting;
* ``import DUAL's learner``: everything a run imports
  (``torchrl_dual.recipe.algos.dual``).

Usage: ``python -m benchmarks.speed.config_error_time [--repeats 7] [--json out.json]``.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.provenance import write_json

COMMANDS = {
    "bad value": ["-m", "torchrl_dual.recipe", "budget.online_frames=-5"],
    "python": ["-c", "pass"],
    "import torch": ["-c", "import torch"],
    "import torchrl": ["-c", "import torchrl"],
    "import DUAL's learner": ["-c", "import torchrl_dual.recipe.algos.dual"],
}


def wall_seconds(args: list[str], cwd: Path) -> tuple[float, subprocess.CompletedProcess]:
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd)
    return time.perf_counter() - start, proc


def measure(repeats: int, cwd: Path) -> dict[str, float]:
    """Median seconds of each command over ``repeats`` alternating rounds."""
    times: dict[str, list[float]] = {name: [] for name in COMMANDS}
    for _ in range(repeats):
        for name, args in COMMANDS.items():
            seconds, proc = wall_seconds(args, cwd)
            expected = 2 if name == "bad value" else 0
            if proc.returncode != expected:
                raise RuntimeError(f"{name}: exit {proc.returncode}\n{proc.stderr}")
            if name == "bad value" and not proc.stderr.startswith("error: budget.online_frames"):
                raise RuntimeError(f"unexpected output: {proc.stderr!r}")
            times[name].append(seconds)
    return {name: statistics.median(values) for name, values in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    medians = measure(args.repeats, cwd=Path.cwd())
    floor = medians["python"]
    print(
        f"median wall seconds over {args.repeats} runs ({platform.processor() or platform.machine()})"
    )
    for name, seconds in medians.items():
        print(f"  {name:<24} {seconds:6.2f} s   x{seconds / floor:5.1f} of python's median")
    ratio = medians["bad value"] / medians["import torch"]
    print(f"bad value / import torch (ratio of medians): {ratio:.2f}")
    if args.json is not None:
        write_json(args.json, {"repeats": args.repeats, "seconds": medians}, indent=1)


if __name__ == "__main__":
    main()
