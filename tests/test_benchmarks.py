"""The benchmark scripts still run end to end (tiny sizes; no timing is asserted)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_latency_benchmark_times_every_candidate_and_writes_json(tmp_path):
    out = tmp_path / "latency.json"
    cmd = [
        sys.executable,
        "benchmarks/latency.py",
        *("--reps", "20", "--warmup", "2", "--rounds", "2"),
        *("--hidden", "32", "--depth", "1", "--teacher-steps", "4"),
        *("--json", str(out)),
    ]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    medians = json.loads(out.read_text())
    assert set(medians) == {
        "mlp_actor",
        "planner_n32",
        "planner_n1",
        "dual_m5",
        "dual_m5_shared",
        "dual_m5_two_pass",
    }
    assert all(value > 0 for value in medians.values())
    assert "goal (restructuring issue #8)" in proc.stdout
