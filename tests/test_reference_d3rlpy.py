"""``python -m benchmarks.learning.reference_d3rlpy``: d3rlpy's IQL as a learner of the
recipe's run, in its own virtual environment, and the learning suite's ``iql_d3rlpy`` /
``calql_d3rlpy`` runs.

The end-to-end test builds the reference venv (d3rlpy from PyPI, the project's packages
through a ``.pth``) in a temporary folder and runs the smoke budget through it, as the
suite does: the summary has the recipe's offline and online evaluations and d3rlpy's
losses are in the recipe's CSV logs, while the project's own environment has no d3rlpy.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.learning import suite as learning

REPO = Path(__file__).resolve().parents[1]

REFERENCE = "benchmarks.learning.reference_d3rlpy"  # run as python -m from the repo root
pytestmark = pytest.mark.long_running(seconds=60)  # starts first under xdist


def test_the_suite_runs_reference_variants_with_the_reference_script(tmp_path):
    args = learning.argparse.Namespace(out=tmp_path, budget="smoke", results=tmp_path)
    suite = learning.Suite(args, [])
    reference = learning.Run("umaze", "iql_d3rlpy", 0, ("algo=iql",))
    recipe = learning.Run("umaze", "iql", 0, ("algo=iql",))
    ours, theirs = suite.command(recipe), suite.command(reference)
    assert ours[1] == "recipes/o2o.py"
    assert theirs[1:3] == ["-m", REFERENCE]
    differ = [(a, b) for a, b in zip(ours[2:], theirs[3:], strict=True) if a != b]
    assert [a.split("=")[0] for a, _ in differ] == ["output_dir"]


@pytest.fixture(scope="module")
def reference_env(tmp_path_factory) -> dict[str, str]:
    """The environment of a reference run whose venv is built in a temporary folder."""
    venv = tmp_path_factory.mktemp("reference") / "venv"
    env = {**os.environ, "TORCHRL_DUAL_REFERENCE_VENV": str(venv), "OMP_NUM_THREADS": "1"}
    setup = subprocess.run(
        [sys.executable, "-m", REFERENCE, "--setup"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert setup.returncode == 0, setup.stderr[-4000:]
    return env


def test_d3rlpy_s_iql_runs_the_recipe_s_smoke_budget_in_its_own_venv(tmp_path, reference_env):
    assert importlib.util.find_spec("d3rlpy") is None, "d3rlpy leaked into the project's env"
    out = tmp_path / "run"
    proc = subprocess.run(
        [
            sys.executable, "-m", REFERENCE, "algo=iql", "budget=smoke",
            "budget.offline_updates=50", "budget.online_frames=100",
            "budget.frames_per_batch=50", "budget.eval_every=100", "budget.eval_episodes=2",
            f"output_dir={out}", f"data_cache_dir={tmp_path / 'data'}", "progress=false",
            "num_threads=1",
        ],
        cwd=REPO, env=reference_env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    summary = json.loads((out / "summary.json").read_text())
    assert [h["label"] for h in summary["history"]] == ["offline", "online"]
    assert summary["updates"] == 50 + 50  # offline, then UTD 0.5 x 100 frames
    losses = out / "logs" / "iql" / "scalars"
    for phase in ("offline", "online"):
        rows = (losses / phase / "d3rlpy_actor_loss.csv").read_text().splitlines()
        assert rows and all(len(row.split(",")) == 2 for row in rows)


def test_an_algorithm_without_a_reference_is_refused_in_one_line(tmp_path, reference_env):
    proc = subprocess.run(
        [sys.executable, "-m", REFERENCE, "algo=dual", f"output_dir={tmp_path}"],
        cwd=REPO, env=reference_env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2 and proc.stderr.strip().splitlines()[-1] == (
        "error: algo=dual: no d3rlpy reference; choose one of iql, calql"
    )
