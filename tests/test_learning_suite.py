"""The learning suite: ``benchmarks/learning/report.py``'s statistics and tables (the
generated section of docs/results.md; ``pairs.py``'s paired differences) and
``benchmarks/learning/suite.py``'s grid, resume and end-to-end run (split from
``tests/test_benchmarks.py``)."""

from __future__ import annotations

import json
import math
import statistics
import sys
from pathlib import Path

import pytest

from benchmarks.learning import report as lr
from benchmarks.learning import suite as learning
from benchmarks.provenance import cpu_model, host_id

pytestmark = pytest.mark.long_running(seconds=10)  # starts first under xdist
HAND_WRITTEN = "# Learning results\n\nIntro written by hand.\n\n## Older runs\n\nkept as is.\n"


# ---------------------------------------------------------------- report.py: statistics and tables
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


def test_the_report_modules_examples_run():
    import doctest

    from benchmarks.learning import claims, equal_time

    for module in (lr, claims, equal_time):
        assert doctest.testmod(module).failed == 0, module.__name__


def test_a_claim_is_a_paired_difference_over_common_seeds():
    from benchmarks.learning import pairs as learning_pairs
    from benchmarks.learning.claims import Claim, claims_table

    def runs(variant, scores, seeds):
        return [_result(variant, s, [0.0, v, v]) for s, v in zip(seeds, scores, strict=True)]

    cells = {
        "umaze": {
            "calql": runs("calql", [10.0, 20.0, 30.0, 99.0], [0, 1, 2, 3]),
            "dual_calql": runs("dual_calql", [14.0, 21.0, 38.0], [0, 1, 2]),
            "so2": runs("so2", [5.0], [0]),
        }
    }
    claims = (
        Claim("umaze", "DUAL on Cal-QL − Cal-QL", "dual_calql", "calql"),
        Claim("umaze", "DUAL on SO2 − SO2", "dual_so2", "so2"),
    )
    table = claims_table(cells, claims).splitlines()
    assert len(table) == 3  # SO2 has no DUAL side: no row
    # seed 3 of calql has no partner: the base's mean is over seeds 0-2 (20.0)
    diffs = [4.0, 1.0, 8.0]
    mean, sd = sum(diffs) / 3, math.sqrt(sum((d - 13 / 3) ** 2 for d in diffs) / 2)
    half = 4.3027 * sd / math.sqrt(3)
    assert _student_t_cdf(4.3027, 2) == pytest.approx(0.975, abs=1e-4)
    assert table[-1].startswith("| umaze | DUAL on Cal-QL − Cal-QL | 0-2 (3) | 20.0 ± ")
    # the interval holds 0; the 90 % one (t(0.95, 2) = 2.92) reaches past +10: not equivalent
    half90 = 2.92 * sd / math.sqrt(3)
    assert mean + half90 > 10 > mean - half90 > -10
    assert f"| +{mean:.1f} ± {half:.1f} ≈ | " in table[-1]  # final, then the AUC
    assert f"| no [{mean - half90:+.1f}, {mean + half90:+.1f}] / " in table[-1]
    assert table[-1].endswith("| no: host not recorded |")  # a commit but no host id
    n, (m, h), marker = learning_pairs.paired_difference(
        runs("d", [12.0, 13.0, 15.0], [0, 1, 2]), runs("b", [10.0, 10.5, 12.0], [0, 1, 2])
    )
    assert (n, marker) == (3, "▲") and m - h > 0


def test_every_claim_names_variants_its_cells_run():
    from benchmarks.learning.cells import CELLS
    from benchmarks.learning.claims import CLAIMS

    for claim in CLAIMS:
        assert claim.a in CELLS[claim.a_cell or claim.cell].variants, claim
        assert claim.b in CELLS[claim.b_cell or claim.cell].variants, claim


def test_the_report_leaves_retired_cells_and_superseded_variants_out_of_its_tables():
    dual = [_result("dual", s, [0.0, 5.0, 10.0 + s]) for s in range(2)]
    old = [_result("iql_tanh_normal", s, [0.0, 1.0, 2.0]) for s in range(2)]
    section = lr.render_section(
        {"umaze": {"dual": dual, "iql_tanh_normal": old}, "medium": {"dual": dual}},
        budget="smoke", header="H", cell_about={"umaze": "U", "medium": "M"},
        variant_order=["dual", "iql_tanh_normal"], figures={}, command="c", results_dir="r",
        retired={"medium": "a goal-conditioned task"},
        superseded={"iql_tanh_normal": "the old actor"},
    )  # fmt: skip
    tables, left_out = section.split("### Not in these tables")
    assert "### umaze: U" in tables and "`dual` | 2 | 0-1 |" in tables
    assert "medium" not in tables and "iql_tanh_normal" not in tables
    assert "* cell `medium` (2 runs): a goal-conditioned task" in left_out
    assert "* variant `iql_tanh_normal` (2 runs): the old actor" in left_out


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


# ---------------------------------------------------------------- suite.py: grid, resume, report
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
        "| `iql` | 3 | 0-2 | 0.0 ± 0.0 | 5.0 ± 2.5 | 2.5 ± 1.2 | 5.0 | — | — | ▼ / ▼ | ? · abc |"
        in first
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
    record = result["provenance"]  # where it ran, read on the node (benchmarks/provenance/)
    assert record["host"] == host_id() and record["cpu"] == cpu_model()
    assert result["commit"] == record["commit"] != "?" and isinstance(record["dirty"], bool)
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
