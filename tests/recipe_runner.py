"""Running ``recipes/o2o.py`` from tests as a user would: a subprocess from the repo root.

``run_recipe`` starts one smoke-budget run; ``succeeded`` and ``failed`` assert on how it
ended (``failed``: exit 2, one ``error:`` line, no traceback).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def run_recipe(output_dir: Path, cache_dir: Path, *overrides: str) -> subprocess.CompletedProcess:
    """``python recipes/o2o.py budget=smoke ...`` from the repo root; never raises."""
    cmd = [
        sys.executable,
        "recipes/o2o.py",
        "budget=smoke",
        f"output_dir={output_dir}",
        f"data_cache_dir={cache_dir}",
        "progress=false",
        "num_threads=1",  # tiny networks: one thread avoids OpenMP contention
        *overrides,
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}
    return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)


def succeeded(proc: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-4000:]}"
    return proc


def failed(proc: subprocess.CompletedProcess) -> str:
    """Asserts exit code 2 with one ``error:`` line on stderr and no traceback; returns it."""
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, f"expected exit 2, got {proc.returncode}\n{out[-4000:]}"
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, proc.stderr[-4000:]
    assert "Traceback" not in out
    return errors[0]
