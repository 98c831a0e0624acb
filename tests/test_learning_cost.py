"""``benchmarks/learning/cost.py``: the learning suite's queue priced from its finished runs."""

from __future__ import annotations

import doctest
from pathlib import Path
from types import SimpleNamespace

from benchmarks.learning import cost as learning_cost

REPO = Path(__file__).resolve().parents[1]

UMAZE = ("env=pointmaze_umaze", "algo=dual")


def _result(seconds: float, overrides=UMAZE, clock: str = "cpu_seconds") -> dict:
    return {clock: seconds, "env": "pointmaze_umaze", "overrides": list(overrides)}


def test_the_docstring_example_holds():
    assert doctest.testmod(learning_cost).failed == 0


def test_a_run_is_priced_by_its_closest_finished_likes():
    results = {
        "umaze": {"dual": [_result(100.0), _result(300.0), _result(200.0)]},
        "umaze_mass": {
            "dual": [_result(1000.0)],
            "dual_calql": [_result(5000.0, (*UMAZE, "critic=calql"))],
        },
        "old": {"iql": [_result(60.0, ("env=pointmaze_umaze", "algo=iql"), "wall_seconds")]},
    }

    def cost(cell, variant, *extra):
        run = SimpleNamespace(cell=cell, variant=variant, overrides=(*UMAZE, *extra))
        return learning_cost.run_cost(run, results)

    assert cost("umaze", "dual") == 200.0  # the same cell's median
    assert cost("umaze_rotation", "dual") == 250.0  # same variant and env: all four's median
    assert cost("umaze_rotation", "dual_calql", "critic=calql") == 5000.0
    assert cost("umaze", "dual_no_uq", "laplace.num_samples=0") == 250.0  # same algo, critic
    assert cost("umaze", "dual_so2", "critic=so2") is None  # nothing like it has run
    iql = SimpleNamespace(
        cell="umaze", variant="iql", overrides=("env=pointmaze_umaze", "algo=iql")
    )
    assert learning_cost.run_cost(iql, results) == 60.0  # wall seconds of an older JSON


def test_an_empty_queue_costs_nothing():
    assert learning_cost.queue_cost_text([], {}, jobs=2) == "nothing to run"


def test_a_run_sharing_an_earlier_run_s_offline_phase_is_priced_online_only():
    """The second run of an offline-sharing group loads the phase from the cache: its likes'
    offline CPU seconds are left out, the first run pays them."""
    result = {**_result(1000.0), "offline_cpu_seconds": 700.0}
    results = {"umaze": {"dual": [result]}}
    run = SimpleNamespace(cell="umaze", variant="dual", overrides=UMAZE)
    assert learning_cost.run_cost(run, results, shares_offline=True) == 300.0
    text = learning_cost.queue_cost_text([run, run], results, jobs=1, shares_offline=[False, True])
    assert "≈ 0.4 CPU-hours for 2 of them" in text  # 1000 + 300 s
