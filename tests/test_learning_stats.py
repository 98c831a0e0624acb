"""``benchmarks/learning/stats.py``: the 90 % t quantiles and the equivalence test (TOST)
of paired differences, and where the report shows its verdict."""

from __future__ import annotations

import doctest
import math
import random
from pathlib import Path

import pytest

from benchmarks.learning import pairs as learning_pairs
from benchmarks.learning import stats as learning_stats

REPO = Path(__file__).resolve().parents[1]

stats = pytest.importorskip("scipy.stats")


def test_the_module_examples_run():
    assert doctest.testmod(learning_stats).failed == 0


def test_t_quantiles_are_students():
    for dof in (*range(1, 31), 31, 45, 60, 120, 1000):
        for p in (0.975, 0.95):
            assert learning_stats.t_quantile(p, dof) == pytest.approx(
                stats.t.ppf(p, dof), abs=1e-4
            ), (p, dof)
    assert learning_stats.t_quantile_975(4) == 2.7764
    with pytest.raises(ValueError, match="p must be one of"):
        learning_stats.t_quantile(0.99, 4)
    with pytest.raises(ValueError, match="dof"):
        learning_stats.t_quantile(0.95, 0)


def test_the_90_interval_uses_the_95_quantile():
    # 1..4: mean 2.5, sd sqrt(5/3); t(0.95, 3) = 2.3534
    mean, half = learning_stats.t_interval([1.0, 2.0, 3.0, 4.0], level=0.90)
    assert (mean, half) == (2.5, pytest.approx(2.3534 * math.sqrt(5 / 3) / 2, rel=1e-12))
    assert learning_stats.t_interval([1.0, 2.0, 3.0, 4.0])[1] == pytest.approx(
        3.1824 * math.sqrt(5 / 3) / 2, rel=1e-12
    )


def test_equivalence_by_hand():
    # 2, 4, 6, 8: mean 5, sd sqrt(20/3), se sqrt(20/3) / 2; t(0.95, 3) = 2.3534
    half = 2.3534 * math.sqrt(20 / 3) / 2  # 3.038
    test = learning_stats.equivalence([2.0, 4.0, 6.0, 8.0], margin=10.0)
    assert (test.low, test.high) == (pytest.approx(5 - half), pytest.approx(5 + half))
    assert test.equivalent and test.text() == "yes [+2.0, +8.0]"
    # the upper end 8.04 reaches past a margin of 8: not shown equivalent
    assert learning_stats.equivalence([2.0, 4.0, 6.0, 8.0], margin=8.0).equivalent is False
    # a mean of 0 but a wide spread: not shown equivalent either
    wide = learning_stats.equivalence([-12.0, 12.0, -6.0, 6.0], margin=10.0)
    assert wide.equivalent is False and wide.low < -10 < 10 < wide.high
    one = learning_stats.equivalence([3.0])
    assert one.equivalent is None and one.text() == "?" and math.isnan(one.low)
    assert learning_stats.equivalence([]).equivalent is None
    assert learning_stats.equivalence([1.0, 2.0]).margin == learning_stats.EQUIVALENCE_MARGIN


def test_equivalence_is_the_two_one_sided_t_tests():
    """The verdict is scipy's two one-sided one-sample t tests, each rejecting at 5 %."""
    rng = random.Random(0)
    verdicts = set()
    for _ in range(200):
        n = rng.randint(2, 8)
        diffs = [rng.gauss(rng.uniform(-12, 12), rng.uniform(0.5, 15)) for _ in range(n)]
        above = stats.ttest_1samp(diffs, -10.0, alternative="greater").pvalue
        below = stats.ttest_1samp(diffs, 10.0, alternative="less").pvalue
        if min(abs(above - 0.05), abs(below - 0.05)) < 1e-3:
            continue  # the tables' 4 decimals decide such a tie, not the test
        tost = bool(above < 0.05 and below < 0.05)
        assert learning_stats.equivalence(diffs, margin=10.0).equivalent is tost, diffs
        verdicts.add(tost)
    assert verdicts == {True, False}


def _run(seed: int, offline: float, final: float, auc: float) -> dict:
    return {"seed": seed, "offline_score": offline, "final_score": final, "auc": auc}


def test_reference_pairs_show_offline_final_and_auc_verdicts():
    assert learning_pairs.reference_pairs() == {
        "iql": "iql_d3rlpy",
        "calql": "calql_d3rlpy",
        "iql_sparse": "iql_d3rlpy_sparse",
        "calql_sparse_no_bound": "calql_d3rlpy_sparse",
    }
    ours = [_run(s, 10.0 + s, 50.0 + 4 * s, 40.0) for s in range(3)]
    ref = [_run(s, 10.0, 50.0, 40.0 + s) for s in range(4)]  # seed 3: no pair
    cells = {"u": {"iql": ours, "iql_d3rlpy": ref}, "v": {"calql": ours}}
    rows = learning_pairs.reference_pairs_table(cells, ["u", "v"]).splitlines()
    assert len(rows) == 3  # v has no reference run: no row
    # offline 0, 1, 2 (sd 1), final 0, 4, 8 (sd 4), AUC 0, -1, -2 (sd 1); t(0.95, 2) = 2.92
    h1, h4 = 2.92 / math.sqrt(3), 2.92 * 4 / math.sqrt(3)  # 1.686, 6.743
    assert rows[-1].startswith("| u | `iql` | `iql_d3rlpy` | 3 | 50.0 ± 0.0 | 54.0 ± 9.9 |")
    assert rows[-1].endswith(
        f"| yes [{1 - h1:+.1f}, {1 + h1:+.1f}] / no [{4 - h4:+.1f}, {4 + h4:+.1f}] "
        f"/ yes [{-1 - h1:+.1f}, {-1 + h1:+.1f}] | no: host not recorded, commit not recorded |"
    )


def test_the_margin_is_stated_once_before_the_claims_and_paired_tables():
    from benchmarks.learning.report import render_section

    history = [{"frames": 0, "normalized_score": 10.0}, {"frames": 8, "normalized_score": 50.0}]
    times = {"offline_seconds": 30.0, "wall_seconds": 60.0, "history": history}
    dual = [_run(s, 10.0, 50.0 + s, 40.0) | times for s in range(3)]
    cells = {"umaze_fresh": {"dual": dual, "iql": dual, "iql_d3rlpy": dual}}
    section = render_section(
        cells, budget="b", header="H", cell_about={"umaze_fresh": "U"}, variant_order=["dual"],
        figures={}, command="c", results_dir="r",
    )  # fmt: skip
    assert section.count("Why ±10") == 1
    assert section.index("Why ±10") < section.index("equivalent within ±10?")
    claims = section.split("### What holds now")[1].split("###")[0]
    assert "| umaze_fresh | DUAL − IQL, same steps | 0-2 (3) |" in claims
    assert "| yes [+0.0, +0.0] / yes [+0.0, +0.0] | level |" in claims  # identical runs
    parts = learning_pairs.pairs_sections(cells, ["umaze_fresh"])
    assert parts[0].startswith("### DUAL against every baseline")
    assert "| yes [+0.0, +0.0] / yes [+0.0, +0.0] |" in parts[2]
    assert parts[-3] == "### Baselines against their reference implementations, seed by seed"
    assert "lower end of the bracket" in parts[-2]  # full strength: the one-sided half
