"""Mutation testing of the core with mutmut (issue 31): which changes to the code the
tests notice.

mutmut changes one operator, constant or call at a time in the target files and runs the
tests that cover the changed function; a *killed* mutant made a test fail, a *survived*
one did not (a test is missing, or the change cannot alter behaviour: an equivalent
mutant, to be listed with its reason). Tests that ``torch.compile`` the code are left out
(dynamo cannot trace mutmut's trampolines). The script works on a clean copy of the commit
(``git archive HEAD``) under ``--workdir``, so the checkout is never touched, and prints
killed / survived / timeout / no-tests per file, with the mutation score
``killed / (killed + survived)``.

Usage (mutmut pinned in the ``mutation`` extra: ``pip install -e ".[mutation]"``)::

    python -m benchmarks.robustness.mutation_testing \\
        --target torchrl_dual/modules/exploration/shift_aware_noise.py \\
        --tests tests/modules/exploration --json out.json

``mutmut show <name>`` (run in ``<workdir>/repo``) prints a surviving mutant's diff.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

from benchmarks.provenance import write_json

REPO = Path(__file__).resolve().parents[2]


def mutmut_config(targets: list[str], tests: list[str], package_files: list[str]) -> str:
    """The ``[tool.mutmut]`` table: mutate ``targets`` only, run ``tests`` only."""
    others = sorted(set(package_files) - set(targets))
    lines = [
        "",
        "[tool.mutmut]",
        'source_paths = ["torchrl_dual/"]',
        f"do_not_mutate = {json.dumps(others)}",
        'also_copy = ["tests/"]',
        f"pytest_add_cli_args_test_selection = {json.dumps(tests)}",
        # torch.compile cannot trace mutmut's trampolines: the compile tests (a graph
        # break is what they check, not an equation) are left out
        'pytest_add_cli_args = ["-p", "no:cacheprovider", "-p", "no:xdist", "-o", "addopts=", '
        '"-k", "not compiles"]',
    ]
    return "\n".join(lines) + "\n"


def prepare(workdir: Path, targets: list[str], tests: list[str]) -> Path:
    """A clean copy of HEAD with the mutmut table, and an empty ``mutants/`` (it must exist
    before the interpreter starts: ``PYTHONPATH`` points there, ahead of the editable
    install of the checkout)."""
    repo = workdir / "repo"
    if repo.exists():
        shutil.rmtree(repo)
    repo.mkdir(parents=True)
    archive = subprocess.run(["git", "archive", "HEAD"], cwd=REPO, capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(repo)], input=archive.stdout, check=True)
    package_files = [str(p.relative_to(repo)) for p in (repo / "torchrl_dual").rglob("*.py")]
    missing = [t for t in targets if t not in package_files]
    if missing:
        raise SystemExit(f"error: --target {missing} not in the package at HEAD")
    with (repo / "pyproject.toml").open("a") as f:
        f.write(mutmut_config(targets, tests, package_files))
    (repo / "mutants").mkdir()
    return repo


def results(repo: Path, env: dict) -> dict[str, Counter]:
    """``file -> Counter(status)`` from ``mutmut results --all true``."""
    out = subprocess.run(
        [sys.executable, "-m", "mutmut", "results", "--all", "true"],
        cwd=repo,
        env=env,
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    by_file: dict[str, Counter] = {}
    for line in out.splitlines():
        name, sep, status = line.strip().partition(": ")
        if not sep or "__mutmut_" not in name:
            continue
        module = name.split("__mutmut_")[0].rsplit(".", 1)[0]  # drop the function's name
        by_file.setdefault(module.replace(".", "/") + ".py", Counter())[status.strip()] += 1
    return by_file


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--target", action="append", required=True, help="file to mutate")
    parser.add_argument("--tests", action="append", required=True, help="tests to run")
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/torchrl_dual_mutation"))
    parser.add_argument("--max-children", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    repo = prepare(args.workdir, args.target, args.tests)
    env = {**os.environ, "PYTHONPATH": str(repo / "mutants")}
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "mutmut", "run", "--max-children", str(args.max_children)],
        cwd=repo,
        env=env,
        check=True,
        stdout=subprocess.DEVNULL,
    )
    seconds = time.perf_counter() - start
    table = results(repo, env)
    print(
        f"mutmut on {len(args.target)} file(s), {seconds / 60:.1f} min, {args.max_children} children"
    )
    print("| file | killed | survived | timeout | no tests | score |")
    print("|---|---|---|---|---|---|")
    for file, counts in sorted(table.items()):
        judged = counts["killed"] + counts["survived"]
        score = f"{100 * counts['killed'] / judged:.1f} %" if judged else "n/a"
        print(
            f"| `{file}` | {counts['killed']} | {counts['survived']} | {counts['timeout']} "
            f"| {counts['no tests']} | {score} |"
        )
    if args.json is not None:
        payload = {"seconds": seconds, "files": {f: dict(c) for f, c in table.items()}}
        write_json(args.json, payload, indent=1)


if __name__ == "__main__":
    main()
