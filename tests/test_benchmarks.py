"""The benchmark scripts still run end to end (tiny sizes; no timing is asserted)."""

from __future__ import annotations

import json
import math
import re
import statistics
import sys
from pathlib import Path

import pytest
from recipe_runner import run_module

from benchmarks.learning import report as lr
from benchmarks.learning import suite as learning
from benchmarks.speed import commit_speed, families, so2_cost

REPO = Path(__file__).resolve().parents[1]


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


def test_every_benchmark_script_is_listed_in_the_benchmarks_readme():
    """Each module of ``benchmarks/<folder>/`` has a row in the README's section of its
    folder (``## `<folder>/` ...``), and the top level holds only the packages."""
    folder = REPO / "benchmarks"
    readme = (folder / "README.md").read_text()
    sections = {
        part.split("`", 1)[0]: part for part in readme.split("\n## `")[1:] if "/`" in part[:40]
    }
    scripts = [
        p
        for p in sorted([*folder.rglob("*.py"), *folder.rglob("*.sh")])
        if p.name not in ("__init__.py", "__main__.py") and "results" not in p.parts
    ]
    assert len(scripts) > 30 and not [p for p in scripts if p.parent == folder]
    listed = {  # folder -> the names in the first column of its section's table rows
        name: {n for row in text.splitlines() if row.startswith("| `") for n in
               re.findall(r"`([^`]+)`", row.split(" | ")[0])}
        for name, text in sections.items()
    }  # fmt: skip
    missing = [
        str(p.relative_to(folder))
        for p in scripts
        if p.name not in listed.get(f"{p.parent.name}/", set())
    ]
    assert not missing, f"add a row to benchmarks/README.md for {missing}"


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


def test_online_reward_counts_the_batches_with_reward_and_the_positive_evaluations(tmp_path):
    from benchmarks.studies import online_reward

    summary = {"history": [
        {"label": "offline", "return": 0.0}, {"label": "online", "return": 0.0},
        {"label": "online", "return": 14.0}, {"label": "online", "return": 0.0},
    ]}  # fmt: skip
    (tmp_path / "results" / "cell" / "dual").mkdir(parents=True)
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    logs = tmp_path / "runs" / "cell" / "dual" / "seed3" / "logs" / "dual" / "scalars" / "online"
    logs.mkdir(parents=True)
    (logs / "reward_per_step.csv").write_text("500,0.0\n1000,0.002\n1500,0.0\n2000,0.01\n")
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "runs", "cell")
    assert records == {"dual": {3: {
        "batches": 4, "batches_with_reward": 2, "first_reward_frames": 1000,
        "evaluations_with_return": 1, "evaluations": 3, "final_return": 0.0,
    }}}  # fmt: skip
    # a JSON that records the batch rewards itself is read without the logs
    summary["online_signals"] = [
        {"frames": 500, "epistemic_share": 0.5, "reward_per_step": 0.0},
        {"frames": 1000, "epistemic_share": 0.5, "reward_per_step": 0.004},
    ]
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "elsewhere", "cell")
    assert records["dual"][3]["batches"] == 2 and records["dual"][3]["first_reward_frames"] == 1000
    del summary["online_signals"][0]["reward_per_step"]  # resumed across the change: the logs
    (tmp_path / "results" / "cell" / "dual" / "seed3.json").write_text(json.dumps(summary))
    records = online_reward.cell_records(tmp_path / "results", tmp_path / "runs", "cell")
    assert records["dual"][3]["batches"] == 4


# ---------------------------------------------------------------- learning suite
# benchmarks/learning/suite.py (grid, resume) and benchmarks/learning/report.py
# (statistics, the generated section of docs/results.md).

pytestmark = pytest.mark.long_running(seconds=40)  # starts first under xdist
HAND_WRITTEN = "# Learning results\n\nIntro written by hand.\n\n## Older runs\n\nkept as is.\n"


def _student_t_cdf(q: float, dof: int, steps: int = 20000) -> float:
    """P(T <= q) by Simpson's rule on the Student-t density (independent of the table)."""
    norm = math.gamma((dof + 1) / 2) / (math.sqrt(dof * math.pi) * math.gamma(dof / 2))
    h = q / steps
    f = [norm * (1 + (i * h) ** 2 / dof) ** (-(dof + 1) / 2) for i in range(steps + 1)]
    return 0.5 + h / 3 * (f[0] + f[-1] + 4 * sum(f[1:-1:2]) + 2 * sum(f[2:-1:2]))


def test_t_quantiles_are_the_975_quantiles_of_student_t():
    for dof in (*range(1, 31), 31, 45, 60, 120):
        assert _student_t_cdf(lr.t_quantile_975(dof), dof) == pytest.approx(0.975, abs=2e-5), dof
    # hand-computed: n = 4, values 1..4: mean 2.5, sd sqrt(5/3), t(0.975, 3) = 3.1824
    mean, half = lr.t_interval([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert half == pytest.approx(3.1824 * math.sqrt(5 / 3) / 2, rel=1e-12)
    assert math.isnan(lr.t_interval([7.0])[1])


def test_separation_marker_needs_non_overlapping_intervals():
    assert lr.separation((10.0, 1.0), (7.0, 1.5)) == "▲"  # 9 > 8.5
    assert lr.separation((5.0, 1.0), (7.0, 0.5)) == "▼"  # 6 < 6.5
    assert lr.separation((10.0, 2.0), (7.0, 1.5)) == "≈"  # 8 <= 8.5
    assert lr.separation((10.0, math.nan), (7.0, 1.0)) == "?"


def _result(variant, seed, scores, offline_s=100.0, wall_s=300.0, cell="umaze", cpu=None):
    """A compact result with evaluations at 0, 50, 100 online frames; ``cpu``: optional
    ``(offline, online)`` CPU seconds."""
    summary = {
        "algo": variant, "env": "pointmaze_umaze", "seed": seed, "budget": "smoke",
        "history": [
            {"label": "offline" if f == 0 else "online", "frames": f, "normalized_score": s,
             "return": 0.0}
            for f, s in zip((0, 50, 100), scores, strict=True)
        ],
        "offline_seconds": offline_s, "wall_seconds": wall_s,
    }  # fmt: skip
    if cpu is not None:
        summary["stage_cpu_seconds"] = {"planner": cpu[0], "online": cpu[1]}
        summary["cpu_seconds"] = cpu[0] + cpu[1]
    meta = {"commit": "abc", "date": "today", "machine": "test box"}
    return lr.compact_result(summary, variant=variant, cell=cell, overrides=[], meta=meta)


def test_auc_is_the_trapezoid_mean_including_the_offline_point():
    curve = [
        {"frames": 0, "normalized_score": 0.0},
        {"frames": 100, "normalized_score": 10.0},
        {"frames": 300, "normalized_score": 10.0},
    ]
    assert lr.online_auc(curve) == pytest.approx((100 * 5 + 200 * 10) / 300)
    result = _result("dual", 0, [0.0, 10.0, 30.0])
    assert result["auc"] == pytest.approx((50 * 5 + 50 * 20) / 100)
    assert (result["offline_score"], result["final_score"]) == (0.0, 30.0)


def test_score_at_wall_time_interpolates_on_the_run_time_axis():
    # evaluations at 0/50/100 frames; offline 100 s, online 200 s -> at 100 s, 200 s, 300 s
    result = _result("dual", 0, [0.0, 10.0, 30.0], offline_s=100.0, wall_s=300.0)
    assert lr.eval_times(result) == [100.0, 200.0, 300.0]
    assert lr.score_at_time(result, 50.0) is None  # still in the offline phase
    assert lr.score_at_time(result, 150.0) == pytest.approx(5.0)
    assert lr.score_at_time(result, 250.0) == pytest.approx(20.0)
    assert lr.score_at_time(result, 999.0) == 30.0  # held after the end
    iql = [_result("iql", s, [0.0, 5.0, 8.0], offline_s=20.0, wall_s=200.0) for s in (0, 1)]
    dual = [_result("dual", s, [0.0, 10.0, 30.0]) for s in (0, 1)]
    table = lr.equal_compute_table({"umaze": {"dual": dual, "iql": iql}}, ["umaze"])
    # T1 = T2 = IQL's 200 s: DUAL at 10 (its 50-frame point), IQL at its final 8
    row = "| umaze | `iql` | 30.0 ± 0.0 | 8.0 ± 0.0 | wall | 3.3 | 10.0 ± 0.0 | 8.0 ± 0.0 | 3.3 |"
    assert row in table
    # every IQL variant of the cell gets its row against the same DUAL runs
    both = lr.equal_compute_table(
        {"umaze": {"dual": dual, "iql": iql, "iql_equal_time": iql[:1]}}, ["umaze"]
    ).splitlines()[2:]
    assert [r.split(" | ")[1] for r in both] == ["`iql`", "`iql_equal_time`"]


def test_equal_time_uses_cpu_seconds_when_every_run_of_the_pair_has_them():
    # wall: DUAL 300 s, IQL 200 s; CPU (alone on a core): DUAL 150 s = 50 + 100, IQL 200 s
    dual = [_result("dual", s, [0.0, 10.0, 30.0], cpu=(50.0, 100.0)) for s in (0, 1)]
    iql = [
        _result("iql", s, [0.0, 5.0, 8.0], offline_s=20.0, wall_s=200.0, cpu=(20.0, 180.0))
        for s in (0, 1)
    ]
    assert lr.eval_times(dual[0], "cpu") == [50.0, 100.0, 150.0]
    assert lr.score_at_time(dual[0], 75.0, "cpu") == pytest.approx(5.0)
    table = lr.equal_compute_table({"umaze": {"dual": dual, "iql": iql}}, ["umaze"])
    # T1 = DUAL's 150 s (2.5 min): DUAL at its end; IQL's evaluations sit at 20, 110 and
    # 200 CPU seconds, so at 150 s it is 40/90 of the way from 5.0 to 8.0
    iql_t1 = 5.0 + (150.0 - 110.0) / 90.0 * 3.0
    assert (
        f"| umaze | `iql` | 30.0 ± 0.0 | 8.0 ± 0.0 | cpu | 2.5 | 30.0 ± 0.0 | {iql_t1:.1f} ± 0.0 |"
        in table
    )
    # one run without CPU seconds: the whole pair falls back to wall-clock time
    iql[1]["cpu_seconds"] = None
    assert "| wall |" in lr.equal_compute_table({"umaze": {"dual": dual, "iql": iql}}, ["umaze"])
    cells = lr.cell_table({"dual": dual}, ["dual"])
    assert "| 5.0 | 2.5 |" in cells  # wall 300 s, CPU 150 s


def _write_fake_results(root: Path) -> None:
    for seed, (d, i) in enumerate([(30.0, 5.0), (32.0, 6.0), (34.0, 4.0)]):
        for variant, final in (("dual", d), ("iql", i)):
            path = root / "smoke" / "umaze" / variant / f"seed{seed}.json"
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(json.dumps(_result(variant, seed, [0.0, final / 2, final])))


def test_report_keeps_hand_written_text_and_is_idempotent(tmp_path, capsys):
    _write_fake_results(tmp_path / "results")
    docs, latency = tmp_path / "results.md", tmp_path / "latency.json"
    docs.write_text(HAND_WRITTEN)
    latency.write_text(json.dumps({"dual_m5": 0.9, "mlp_actor": 0.1}))
    argv = [
        *("--budget", "smoke", "--report-only", "--latency-json", str(latency)),
        *("--results", str(tmp_path / "results"), "--docs", str(docs)),
        *("--figures", str(tmp_path / "figures")),
    ]
    begin, end = lr.markers("smoke")
    assert learning.main(argv) == 0
    first = docs.read_text()
    assert first.startswith("# Learning results\n\n" + begin)
    assert first.endswith(end + "\n\nIntro written by hand.\n\n## Older runs\n\nkept as is.\n")
    assert (
        "| `iql` | 3 | 0.0 ± 0.0 | 5.0 ± 2.5 | 2.5 ± 1.2 | 5.0 | — | — | ▼ / ▼ |" in first
    )  # t(2)=4.3027
    assert "### DUAL vs IQL at equal steps and at equal wall time" in first
    # the cost paragraph: the finished runs' total and the rest of the grid (6 done)
    assert "**Cost.** The 6 runs here took 0.5 CPU-hours (0.5 hours of wall time" in first
    assert ", 6 already done, " in first.split("**Cost.**")[1].split("\n")[0]
    for png in ("learning_smoke_umaze.png", "latency_vs_score_smoke.png"):
        assert (tmp_path / "figures" / png).stat().st_size > 1000
        assert f"(figures/{png})" in first
    assert learning.main(argv) == 0
    second = docs.read_text()
    assert lr.replace_section(second, "X", "smoke") == lr.replace_section(first, "X", "smoke")
    assert second.count(begin) == 1 and second.split(end)[1] == first.split(end)[1]
    # another budget's section is added above and leaves this one as it is
    other = lr.replace_section(
        second, "<!-- learning-suite:paper:begin -->P<!-- learning-suite:paper:end -->", "paper"
    )
    assert other.split(begin, 1)[1] == second.split(begin, 1)[1]
    assert other.index("learning-suite:paper:begin") < other.index(begin)


def test_resume_skips_runs_with_a_json_and_continues_checkpointed_ones(tmp_path, capsys):
    _write_fake_results(tmp_path / "results")  # umaze dual/iql seeds 0-2 are done
    out = tmp_path / "out"
    (out / "smoke" / "umaze" / "dual" / "seed3").mkdir(parents=True)
    (out / "smoke" / "umaze" / "dual" / "seed3" / "checkpoint.pt").write_bytes(b"")
    argv = [
        *("--budget", "smoke", "--cells", "umaze", "--variants", "dual", "iql", "dual_lambda0"),
        *("--results", str(tmp_path / "results"), "--out", str(out), "--dry-run"),
        "budget.online_frames=200",
    ]
    assert learning.main(argv) == 0
    printed = capsys.readouterr().out
    assert "15 runs in the grid, 6 already done, 9 to run" in printed
    queue = [line for line in printed.splitlines() if line.startswith("recipes/o2o.py")]
    assert len(queue) == 9 and all(line.endswith("budget.online_frames=200") for line in queue)
    resumed = [line for line in queue if "resume=true" in line]
    assert len(resumed) == 1 and "umaze/dual/seed3" in resumed[0]
    # seeds 3, 4 of dual lead their offline-sharing groups: before every dual_lambda0 run
    first_lambda0 = next(i for i, line in enumerate(queue) if "shift_weight=0" in line)
    assert all("algo=dual " in line and "shift_weight" not in line for line in queue[:2])
    assert first_lambda0 >= 4  # dual seeds 3, 4 and iql seeds 3, 4 lead


def test_learning_suite_runs_one_tiny_cell_end_to_end_and_then_nothing(tmp_path, capsys):
    docs = tmp_path / "results.md"
    docs.write_text(HAND_WRITTEN)
    flags = [
        *("--budget", "smoke", "--cells", "frozenlake8x8_slip", "--variants", "iql"),
        *("--seeds", "0", "--jobs", "1", "--out", str(tmp_path / "out")),
        *("--results", str(tmp_path / "results"), "--docs", str(docs)),
        *("--figures", str(tmp_path / "figures")),
        *("budget.offline_updates=10", "budget.online_frames=100", "budget.frames_per_batch=50"),
        *("budget.eval_every=50", "budget.eval_episodes=1", "budget.checkpoint_every=50"),
    ]
    # in-process (the recipe run itself is a subprocess): saves importing torch again
    assert learning.main(flags) == 0, capsys.readouterr()
    printed = capsys.readouterr()
    path = tmp_path / "results" / "smoke" / "frozenlake8x8_slip" / "iql" / "seed0.json"
    result = json.loads(path.read_text())
    assert (result["variant"], result["algo"], result["shift"]) == ("iql", "iql", "biased_slip")
    assert [h["frames"] for h in result["history"]] == [0, 50, 100]
    assert result["wall_seconds"] >= result["offline_seconds"] > 0
    assert "frozenlake8x8_slip iql seed0: final score" in printed.out + printed.err
    assert "### frozenlake8x8_slip" in docs.read_text()
    stamp = path.stat().st_mtime_ns
    assert learning.main(flags) == 0  # in-process: nothing left to run
    assert "1 runs in the grid, 1 already done, 0 to run" in capsys.readouterr().out
    assert path.stat().st_mtime_ns == stamp


def test_a_failed_run_prints_its_stderr_tail_and_the_suite_exits_nonzero(
    tmp_path, capsys, monkeypatch
):
    crash = "import sys; sys.stderr.write('error: boom in the recipe'); sys.exit(2)"
    monkeypatch.setattr(learning.Suite, "command", lambda self, run: [sys.executable, "-c", crash])
    monkeypatch.setattr(learning, "machine", lambda: "test box")
    argv = [
        *("--budget", "smoke", "--cells", "medium", "--variants", "iql", "--seeds", "0", "1"),
        *("--out", str(tmp_path / "out"), "--results", str(tmp_path / "results")),
        *("--docs", str(tmp_path / "results.md"), "--figures", str(tmp_path / "figures")),
    ]
    assert learning.main(argv) == 1
    printed = capsys.readouterr()
    assert printed.out.count("error: boom in the recipe") == 2  # both runs, both reported
    assert "2 runs failed: medium/iql/seed0, medium/iql/seed1" in printed.err
    assert not (tmp_path / "results" / "smoke").exists()
    assert "No results yet." in (tmp_path / "results.md").read_text()


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
    (row,) = json.loads(out.read_text())
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
    assert "SO2 / IQL critic update:" in out


def test_shift_cells_report_the_offline_score_without_the_shift():
    runs = []
    for seed, (shifted, plain) in enumerate([(4.0, 20.0), (6.0, 40.0)]):
        result = _result("dual", seed, [shifted, 10.0, 30.0], cell="umaze_rotation")
        result["shift"] = "rotation"
        result["history"][0]["normalized_score_unshifted"] = plain
        runs.append(result)
    table = lr.cell_table({"dual": runs}, ["dual"])
    assert "| offline score | offline, no shift | final online score |" in table
    half = 12.706 * (20.0 / math.sqrt(2)) / math.sqrt(2)  # t_0.975(1) * s / sqrt(n)
    assert f"| 5.0 ± {12.706 * 1.0:.1f} | 30.0 ± {half:.1f} |" in table
    plain = lr.cell_table({"dual": [_result("dual", 0, [1.0, 2.0, 3.0])]}, ["dual"])
    assert "no shift" not in plain


def test_dual_against_its_base_critic_is_a_paired_difference_over_common_seeds():
    from benchmarks.learning import pairs as learning_pairs

    def runs(variant, scores, seeds):
        return [_result(variant, s, [0.0, v, v]) for s, v in zip(seeds, scores, strict=True)]

    cells = {
        "umaze": {
            "calql": runs("calql", [10.0, 20.0, 30.0, 99.0], [0, 1, 2, 3]),
            "dual_calql": runs("dual_calql", [14.0, 21.0, 38.0], [0, 1, 2]),
            "so2": runs("so2", [5.0], [0]),
        }
    }
    table = learning_pairs.critic_pairs_table(cells, ["umaze"]).splitlines()
    assert len(table) == 3  # SO2 has no DUAL side: no row
    # seed 3 of calql has no partner: the base's mean is over seeds 0-2 (20.0)
    diffs = [4.0, 1.0, 8.0]
    mean, sd = sum(diffs) / 3, math.sqrt(sum((d - 13 / 3) ** 2 for d in diffs) / 2)
    half = 4.3027 * sd / math.sqrt(3)
    assert _student_t_cdf(4.3027, 2) == pytest.approx(0.975, abs=1e-4)
    assert table[-1].startswith("| umaze | Cal-QL | 3 | 20.0 ± ")
    # the interval holds 0; the 90 % one (t(0.95, 2) = 2.92) reaches past +10: not equivalent
    half90 = 2.92 * sd / math.sqrt(3)
    assert mean + half90 > 10 > mean - half90 > -10
    assert table[-1].endswith(
        f"| +{mean:.1f} ± {half:.1f} ≈ | no [{mean - half90:+.1f}, {mean + half90:+.1f}] |"
    )
    n, (m, h), marker = learning_pairs.paired_difference(
        runs("d", [12.0, 13.0, 15.0], [0, 1, 2]), runs("b", [10.0, 10.5, 12.0], [0, 1, 2])
    )
    assert (n, marker) == (3, "▲") and m - h > 0


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
    rows = json.loads(out.read_text())
    assert [(r["collector"], r["workers"]) for r in rows] == [("single", 1), ("multi_async", 1)]
    assert all(r["steps_per_second"] > 0 for r in rows)
    assert "| pointmaze | random | multi_async | 1 |" in proc.stdout


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


def test_mutation_testing_mutates_the_targets_only_and_counts_per_file(monkeypatch):
    """The mutmut table keeps every other package file out, and ``mutmut results`` lines
    are counted per source file (class methods and functions alike)."""
    import subprocess as sp

    import tomllib

    from benchmarks.robustness import mutation_testing

    table = tomllib.loads(
        mutation_testing.mutmut_config(
            ["torchrl_dual/a.py"], ["tests/x"], ["torchrl_dual/a.py", "torchrl_dual/b.py"]
        )
    )["tool"]["mutmut"]
    assert table["do_not_mutate"] == ["torchrl_dual/b.py"]
    assert table["pytest_add_cli_args_test_selection"] == ["tests/x"]
    out = "\n".join(
        [
            "    torchrl_dual.m.a.xǁCǁ__init____mutmut_1: killed",
            "    torchrl_dual.m.a.xǁCǁforward__mutmut_2: survived",
            "    torchrl_dual.m.a.x_helper__mutmut_1: killed",
            "    torchrl_dual.b.x_f__mutmut_1: no tests",
        ]
    )
    monkeypatch.setattr(sp, "run", lambda *a, **k: sp.CompletedProcess(a, 0, stdout=out))
    counts = mutation_testing.results(REPO, {})
    assert counts["torchrl_dual/m/a.py"] == {"killed": 2, "survived": 1}
    assert counts["torchrl_dual/b.py"] == {"no tests": 1}


# ---------------------------------------------------------------- kill -9 and resume
def test_resume_kill_benchmark_kills_resumes_and_finds_the_runs_equal(tmp_path):
    """``python -m benchmarks.robustness.resume_kill`` on IQL / Frozen-Lake at a tiny
    budget: the run is SIGKILLed after its online evaluation at 100 frames, resumed, and
    ends bitwise as the uninterrupted run (issue 31; the contract test checks every
    algorithm in-process)."""
    out = tmp_path / "resume_kill.json"
    tiny = [
        "env=frozenlake",
        "budget.dataset_transitions=1000",
        "budget.network_width=16",
        "budget.offline_updates=4",
        "budget.online_frames=300",
        "budget.frames_per_batch=50",
        "budget.eval_every=100",
        "budget.eval_episodes=1",
        "budget.checkpoint_every=50",
    ]
    proc = run_module(
        "benchmarks.robustness.resume_kill",
        *("--algo", "iql", "--kill-after", "100", "--kill-delay", "0"),
        *("--out", str(tmp_path / "runs"), "--json", str(out), "--", *tiny),
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    result = json.loads(out.read_text())
    assert result["differences"] == [] and result["entries_compared"] > 100
    assert result["final_frames"] == [300, 300]
    assert 50 <= result["checkpoint_frames_at_kill"] < 300


def test_the_cell_table_reports_each_variant_s_epistemic_share():
    """The share of Eq. 9's epistemic variance in the executed one (issue 29): each run's
    mean over its batches, then mean ± t half-width over seeds, in percent; "—" when a run
    did not log it."""

    def run(seed: int, shares: list[float] | None) -> dict:
        signals = [
            {"frames": 100 * (i + 1), "epistemic_share": x} for i, x in enumerate(shares or [])
        ]
        return {
            "seed": seed, "offline_score": 0.0, "final_score": 1.0, "auc": 1.0,
            "wall_seconds": 60.0, "online_signals": signals,
        }  # fmt: skip

    assert lr.epistemic_share(run(0, [0.1, 0.3])) == pytest.approx(0.2)
    assert lr.epistemic_share(run(0, None)) is None
    table = lr.cell_table(
        {
            "dual": [run(0, [0.1, 0.3]), run(1, [0.4]), run(2, [0.2, 0.2])],  # 20, 40, 20 %
            "iql": [run(0, None), run(1, None)],
        },
        ["dual", "iql"],
    )
    half = 4.3027 * statistics.stdev([20.0, 40.0, 20.0]) / math.sqrt(3)
    assert f"| 26.7 ± {half:.1f} % |" in table.splitlines()[2]
    assert "| — |" in table.splitlines()[3]
    # runs that logged only the stds: an upper bound (std² over the mean executed std²)
    stds = {"frames": 100, "epistemic_std": 0.1, "exploration_std": 0.5}
    older = run(2, None) | {"online_signals": [stds, stds | {"epistemic_std": 0.2}]}
    assert lr.epistemic_share_bound(older) == pytest.approx((0.04 + 0.16) / 2)
    assert lr.share_text([run(0, [0.3]), older]) == "≤ 20.0 %"  # (30 % + 10 %) / 2
    assert lr.share_text([run(0, [0.1]), run(1, None)]) == "—"


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
