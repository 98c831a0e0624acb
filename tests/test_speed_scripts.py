"""The scripts of ``benchmarks/speed/`` still run end to end (tiny sizes; no timing is
asserted), and the pure parts of their projections (split from ``tests/test_benchmarks.py``;
``gpu_throughput.py`` has its own ``tests/test_gpu_throughput.py``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from recipe_runner import run_module

from benchmarks.speed import commit_speed, families, so2_cost

REPO = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.long_running(seconds=25)  # starts first under xdist


# ---------------------------------------------------------------- latency
def test_latency_benchmark_times_every_candidate_and_writes_json(tmp_path):
    out = tmp_path / "latency.json"
    proc = run_module(
        "benchmarks.speed.latency",
        *("--reps", "20", "--warmup", "2", "--rounds", "2"),
        *("--hidden", "32", "--depth", "1", "--teacher-steps", "4"),
        *("--json", str(out)),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    medians = json.loads(out.read_text())
    assert medians.pop("provenance")["commit"] != "?"  # benchmarks/provenance/
    assert set(medians) == {
        "mlp_actor",
        "planner_n32",
        "planner_n1",
        "dual_m5",
        "dual_m5_shared",
        "dual_m5_two_pass",
        "dual_m5_n8",
        "dual_m5_latent",
        "iql_actor",
        "iql_la_m5",
        "diffql_n5",
        "diffql_la_m5",
        "dacer_n5",
    }
    assert all(value > 0 for value in medians.values())
    assert "goal (restructuring issue #8)" in proc.stdout


def test_the_gpu_check_script_parses_and_refuses_a_machine_without_cuda(tmp_path):
    """``benchmarks/speed/gpu_check.sh`` runs on a GPU machine only; here: its syntax, and
    that it stops at once (exit 2) where there is no CUDA device."""
    import os
    import subprocess

    import torch

    script = REPO / "benchmarks" / "speed" / "gpu_check.sh"
    assert subprocess.run(["bash", "-n", str(script)]).returncode == 0
    if not torch.cuda.is_available():
        env = {**os.environ, "OUT": str(tmp_path / "out")}
        proc = subprocess.run(["bash", str(script)], cwd=REPO, env=env, capture_output=True)
        assert proc.returncode == 2, proc.stderr[-500:]


# ---------------------------------------------------------------- env families
def test_paper_projection_multiplies_each_cost_by_the_paper_budget():
    unit = dict.fromkeys(
        (
            "planner_update_ms",
            "distill_update_ms",
            "actor_critic_update_ms",
            "laplace_ms_per_1k_transitions",
            "online_step_ms",
            "eval_step_ms",
        ),
        3.6,  # 3.6 ms: one hour per million
    )
    hours = families.projection_hours(unit, max_episode_steps=1000)
    assert hours["planner"] == pytest.approx(1.0) and hours["actor_critic"] == pytest.approx(1.0)
    assert hours["distillation"] == pytest.approx(0.1)
    assert hours["online_updates"] == pytest.approx(0.5) and hours["online_steps"] == pytest.approx(
        1.0
    )
    assert hours["evaluation"] == pytest.approx(21 * 100 * 1000 / 1e6)
    # 51 fits (one offline + 50 refits in 500k online updates) over 1M offline + on average
    # 0.5M online transitions
    assert hours["laplace"] == pytest.approx(51 * 1500 / 1e6)
    assert hours["total"] == pytest.approx(sum(v for k, v in hours.items() if k != "total"))


@pytest.mark.skipif(
    __import__("importlib").util.find_spec("minari") is None, reason="needs minari[hdf5]"
)
def test_families_benchmark_runs_on_a_stand_in_data_set(tmp_path):
    out = tmp_path / "families.json"
    args = ["--families", "hopper", "--updates", "5", "--steps", "20", "--json", str(out)]
    proc = run_module("benchmarks.speed.families", *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    (row,) = json.loads(out.read_text())["rows"]
    assert (row["family"], row["obs_dim"], row["action_dim"]) == ("hopper", 11, 3)
    assert all(
        row[k] > 0 for k in ("planner_update_ms", "actor_critic_update_ms", "online_step_ms")
    )
    assert row["paper_budget_cpu_hours"]["total"] > 0


def test_ant_controller_cost_projects_minaris_budget():
    args = ["--updates", "2", "--steps", "20", "--width", "32", "--depth", "1"]
    proc = run_module("benchmarks.speed.ant_controller_cost", *args, "--batch-size", "16")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "| Minari's train_ant.py | 30,000,000 | 1,875,000 |" in proc.stdout


# ---------------------------------------------------------------- SO2 + balanced replay cost
def test_so2_cost_prints_the_three_updates_and_the_ratio(monkeypatch, capsys):
    argv = ["so2_cost.py", "--updates", "1", "--members", "2", "--width", "8"]
    argv += ["--batch-size", "4", "--replay-size", "16"]
    monkeypatch.setattr(sys, "argv", argv)
    so2_cost.main()
    out = capsys.readouterr().out
    for row in ("| SO2 critic, E = 2 |", "| IQL critic (twin Q + V) |", "N = 16 |"):
        assert row in out
    assert "SO2 / IQL critic update (ratio of mean CPU ms):" in out


# ---------------------------------------------------------------- collectors.py
def test_collectors_benchmark_times_single_and_a_worker_collector(tmp_path):
    # multi_async only: a spawned worker costs ≈ 10 s here, Ray ≈ 20 s more (its runtime
    # and one actor); the recipe's collector=ray has its own test (test_ray_collector.py)
    out = tmp_path / "collectors.json"
    proc = run_module(
        "benchmarks.speed.collectors",
        *("--envs", "pointmaze", "--policies", "random", "--workers", "1"),
        *("--frames", "40", "--batch", "20", "--collectors", "multi_async"),
        *("--json", str(out)),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = json.loads(out.read_text())["rows"]
    assert [(r["collector"], r["workers"]) for r in rows] == [("single", 1), ("multi_async", 1)]
    assert all(r["steps_per_second"] > 0 for r in rows)
    assert "| pointmaze | random | multi_async | 1 |" in proc.stdout


# ---------------------------------------------------------------- update cost
def test_ensemble_eval_benchmark_checks_equality_and_prints_the_ratio():
    args = ("--members", "2", "3", "--reps", "2", "--rounds", "1", "--width", "16")
    proc = run_module("benchmarks.speed.ensemble_eval", *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = [line for line in proc.stdout.splitlines() if line.startswith("| 2 |")]
    assert len(rows) == 1 and rows[0].endswith("x |")


def test_commit_speed_imports_each_side_from_its_own_exported_tree(tmp_path):
    """The speed comparison is only meaningful if the ``before`` process runs the exported
    revision's code, not this checkout's (Python puts the working directory first)."""
    tree = commit_speed.export_tree("HEAD", tmp_path / "before")
    assert (tree / "recipes" / "o2o.py").is_file() and not (tree / ".git").exists()
    assert commit_speed.imported_from(tree, tmp_path) == tree
    assert commit_speed.imported_from(REPO, tmp_path) == REPO


def test_config_error_time_measures_the_bad_value_and_its_floor(monkeypatch):
    """The benchmark's commands behave as it expects (exit 2 and one error line for the
    bad value); timed once, without the heavy imports."""
    from benchmarks.speed import config_error_time

    commands = {k: config_error_time.COMMANDS[k] for k in ("bad value", "python")}
    monkeypatch.setattr(config_error_time, "COMMANDS", commands)
    medians = config_error_time.measure(1, cwd=REPO)
    assert set(medians) == {"bad value", "python"}
    assert all(seconds > 0 for seconds in medians.values())


def test_collection_speed_times_each_env_count_and_its_ratio(tmp_path):
    out = tmp_path / "collection_speed.json"
    proc = run_module(
        "benchmarks.speed.collection_speed",
        *("--envs", "pointmaze", "--num-envs", "1", "2", "--batch", "4"),
        *("--frames", "8", "--rounds", "2", "--json", str(out)),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = json.loads(out.read_text())["pointmaze"]["num_envs"]
    assert set(rows) == {"1", "2"}
    assert rows["1"]["ratio_to_1"] == 1.0 and rows["2"]["ratio_to_1"] > 0
    assert all(len(row["steps_per_s_all"]) == 2 for row in rows.values())
    assert "| pointmaze | 2 |" in proc.stdout


def test_update_speed_times_ours_and_d3rlpys_updates_and_profiles_them(tmp_path):
    out = tmp_path / "update_speed.json"
    with_d3rlpy = (REPO / ".venv-reference" / "bin" / "python").exists()
    proc = run_module(
        "benchmarks.speed.update_speed",
        *("--width", "16", "--batch", "8", "--batches", "2", "--warmup", "1"),
        *("--updates", "2", "--rounds", "2", "--profile", "2", "--json", str(out)),
        *(() if with_d3rlpy else ("--no-d3rlpy",)),
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(out.read_text())
    names = {"iql", "calql", "dual"} | ({"iql_d3rlpy", "calql_d3rlpy"} if with_d3rlpy else set())
    assert set(result["ms_per_update_all"]) == names
    assert all(len(v) == 2 for v in result["ms_per_update_all"].values())
    assert "dual/iql" in result["ratios"]
    assert with_d3rlpy == ("iql/iql_d3rlpy" in result["ratios"])
    assert set(result["profile"]) == {"iql", "calql", "dual"}
    assert "| dual |" in proc.stdout


def test_finite_checks_times_both_sides_and_writes_the_ratio(tmp_path):
    from benchmarks.speed import finite_checks

    out = tmp_path / "checks.json"
    report = finite_checks.main(["--tiny", "--updates", "2", "--rounds", "2", "--json", str(out)])
    assert len(report["ms_per_update_checks_on"]) == len(report["ms_per_update_checks_off"]) == 2
    assert (
        report["ratio_of_medians_on_over_off"] == report["median_on_ms"] / report["median_off_ms"]
    )
    assert "provenance" in json.loads(out.read_text())
