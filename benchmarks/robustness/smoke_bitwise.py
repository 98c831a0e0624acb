"""Does a change keep every algorithm's results? ``budget=smoke`` runs, compared bit for bit.

    python -m benchmarks.robustness.smoke_bitwise record outputs/smoke_before   # on the old code
    python -m benchmarks.robustness.smoke_bitwise record outputs/smoke_after    # on the new code
    python -m benchmarks.robustness.smoke_bitwise compare outputs/smoke_before outputs/smoke_after

``record`` runs the recipe at ``budget=smoke`` (``num_threads=1``, one process each, the
command line's own steps) for every algorithm of ``ALGORITHMS`` and DUAL with each other
critic, one run directory each. ``compare`` says, per run, whether the evaluation history
of ``summary.json`` and every scalar CSV of the logs are byte for byte equal, and exits 1
if one is not. A refactoring that draws no random number in another order keeps them all.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from torchrl_dual.recipe import ALGORITHMS, CRITICS


def runs() -> dict[str, list[str]]:
    """Run name -> its overrides: each algorithm, then DUAL with each other critic."""
    table = {algo: [f"algo={algo}"] for algo in ALGORITHMS}
    for critic in CRITICS:
        if critic != "iql" and critic in ALGORITHMS["dual"].settings.critics:
            table[f"dual_{critic}"] = ["algo=dual", f"critic={critic}"]
    return table


def record(out: Path) -> None:
    """Runs every entry of :func:`runs` at ``budget=smoke`` into ``out/<name>`` (its log:
    ``out/<name>.log``)."""
    out.mkdir(parents=True, exist_ok=True)
    for name, overrides in runs().items():
        command = [sys.executable, "-m", "torchrl_dual.recipe", *overrides, "budget=smoke"]
        command += ["progress=false", "num_threads=1", f"output_dir={out / name}"]
        done = subprocess.run(command, capture_output=True, text=True)
        (out / f"{name}.log").write_text(done.stdout + done.stderr)
        print(f"{name}: exit {done.returncode}", flush=True)


def differences(before: Path, after: Path) -> list[str]:
    """What differs between two run directories: the history, a CSV (missing or changed)."""
    if not (after / "summary.json").exists():
        return ["no summary.json (the run failed: its log says why)"]
    found = []
    history = [json.loads((d / "summary.json").read_text())["history"] for d in (before, after)]
    if history[0] != history[1]:
        found.append("summary.json history")
    for csv in sorted(before.rglob("*.csv")):
        other = after / csv.relative_to(before)
        if not other.exists() or other.read_bytes() != csv.read_bytes():
            found.append(str(csv.relative_to(before)))
    return found


def compare(before: Path, after: Path) -> bool:
    """Prints, per run both directories hold, whether it is bitwise equal; all equal?"""
    equal = True
    for name in runs():
        if not (before / name / "summary.json").exists() or not (after / name).exists():
            continue  # not recorded on both sides
        found = differences(before / name, after / name)
        equal &= not found
        print(f"{name}: {'bitwise equal' if not found else 'differs: ' + ', '.join(found[:5])}")
    return equal


def main(argv: list[str] | None = None) -> int:
    """``record OUT`` or ``compare BEFORE AFTER``; returns the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("action", choices=["record", "compare"])
    parser.add_argument("dirs", nargs="+", type=Path)
    args = parser.parse_args(argv)
    if args.action == "record":
        record(args.dirs[0])
        return 0
    return 0 if compare(*args.dirs[:2]) else 1


if __name__ == "__main__":
    sys.exit(main())
