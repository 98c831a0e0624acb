"""``benchmarks/learning/pairs.py``: DUAL's variants paired with DUAL by seed."""

from __future__ import annotations

import doctest
from pathlib import Path

import pytest

from benchmarks.learning import pairs as learning_pairs

REPO = Path(__file__).resolve().parents[1]


def _run(
    seed: int, offline: float, final: float, auc: float | None = None, host: str = "h"
) -> dict:
    record = {"host": host, "commit": "c0ffee", "dirty": False}
    return {
        "seed": seed, "offline_score": offline, "final_score": final, "auc": auc or final,
        "provenance": record,
    }  # fmt: skip


def test_the_module_examples_run():
    assert doctest.testmod(learning_pairs).failed == 0


def test_dual_variants_pair_with_dual_by_seed_and_report_shared_offline_phases():
    dual = [_run(0, 20.0, 50.0, 40.0), _run(1, 30.0, 60.0, 50.0), _run(2, 25.0, 55.0, 45.0)]
    no_uq = [_run(0, 20.0, 48.0, 41.0), _run(1, 30.0, 57.0, 50.0), _run(2, 25.0, 51.0, 45.0)]
    lambda0 = [_run(1, 31.0, 70.0), _run(3, 10.0, 99.0)]  # seed 3: no DUAL partner
    cells = {
        "umaze": {"dual": dual, "dual_no_uq": no_uq, "dual_lambda0": lambda0, "iql": dual},
        "umaze_online": {"dual_utd025": [_run(0, 20.0, 45.0), _run(2, 25.0, 50.0)]},
        "no_dual": {"dual_lambda0": lambda0},  # no `dual` to pair with: no row
    }
    rows = learning_pairs.dual_variant_pairs_table(
        cells, ["umaze", "umaze_online", "no_dual"], {"umaze_online": "umaze"}
    ).splitlines()[2:]
    assert [r.split(" | ")[:4] for r in rows] == [
        ["| umaze", "`dual_no_uq` (`laplace.num_samples=0`)", "3", "3/3"],
        ["| umaze", "`dual_lambda0` (`exploration.shift_weight=0`)", "1", "0/1"],
        ["| umaze_online", "`dual_utd025` (`online.utd_ratio=0.25`)", "2", "2/2"],
    ]
    # no-UQ − DUAL: -2, -3, -4 (final, sd 1) and +1, 0, 0 (AUC, sd √(1/3)); t(2) = 4.3027
    final, auc = 4.3027 / 3**0.5, 4.3027 * (1 / 3) ** 0.5 / 3**0.5
    # and their 90 % intervals, t(0.95, 2) = 2.9200: -3 ± 1.686, 1/3 ± 0.973, inside ±10
    low, high = -3.0 - 2.92 / 3**0.5, 1 / 3 + 2.92 * (1 / 3) ** 0.5 / 3**0.5
    assert rows[0].endswith(
        f"| -3.0 ± {final:.1f} ▼ | +0.3 ± {auc:.1f} ≈ | yes [{low:+.1f}, -1.3] / yes [-0.6, "
        f"{high:+.1f}] | yes |"
    )
    assert rows[1].endswith("| +10.0 ? | +20.0 ? | ? / ? | yes |")  # one pair: no interval
    n, (mean, _), _ = learning_pairs.paired_difference(cells["umaze_online"]["dual_utd025"], dual)
    assert (n, mean) == (2, pytest.approx(-5.0))


def test_every_baseline_pairs_with_the_dual_runs_of_its_reference_cell():
    """The paper's main claim, seed by seed: each non-DUAL variant against the `dual` of
    its own cell, or of the cell ``dual_from`` names (umaze_baselines: umaze_ablations);
    DUAL's own variants and cells without a reference have no row."""
    from benchmarks.learning import variants

    dual = [_run(0, 20.0, 50.0, 40.0), _run(1, 30.0, 60.0, 50.0), _run(2, 25.0, 55.0, 45.0)]
    cells = {
        "umaze": {
            "dual": dual,
            "iql": [_run(0, 9.0, 30.0), _run(1, 9.0, 41.0)],
            "dual_no_uq": dual,
        },
        "umaze_ablations": {"dual": [_run(s, 0.0, 10.0 + s) for s in range(3)]},
        "umaze_baselines": {"edis": [_run(s, 0.0, 5.0) for s in range(3)]},
        "medium": {"iql": dual},  # no dual there: no row
    }
    order = ["umaze", "umaze_ablations", "umaze_baselines", "medium"]
    dual_from = {"umaze_baselines": "umaze_ablations"}
    rows = learning_pairs.baseline_pairs_table(cells, order, dual_from).splitlines()[2:]
    assert [r.split(" | ")[:4] for r in rows] == [
        ["| umaze", "`iql`", "2", "umaze"],
        ["| umaze_baselines", "`edis`", "3", "umaze_ablations"],
    ]
    # DUAL − iql: +20, +19 (t(1) = 12.706, sd 1/√2); DUAL − edis: +5, +6, +7 (sd 1)
    assert rows[0].split(" | ")[6] == f"+19.5 ± {12.706 * 0.5:.1f} ▲"
    assert rows[1].split(" | ")[6] == f"+6.0 ± {4.3027 / 3**0.5:.1f} ▲"
    assert set(variants.baseline_variants()) >= {"iql", "diffuser", "dacer", "edis"}
    assert not {"dual", "dual_no_uq", "dual_calql"} & set(variants.baseline_variants())


def test_a_pair_that_crosses_hosts_commits_or_a_dirty_tree_is_marked():
    """Only the paired seeds count: an unpaired run on another host changes nothing."""
    dual = [_run(0, 20.0, 50.0), _run(1, 30.0, 60.0)]
    same = [_run(0, 20.0, 40.0), _run(1, 30.0, 50.0), _run(7, 0.0, 0.0, host="elsewhere")]
    moved = [_run(0, 20.0, 40.0), _run(1, 30.0, 50.0, host="elsewhere")]
    edited = [_run(0, 20.0, 40.0), _run(1, 30.0, 50.0)]
    edited[1]["provenance"] = {**edited[1]["provenance"], "commit": "beef", "dirty": True}
    older = [{k: v for k, v in r.items() if k != "provenance"} | {"commit": "c0ffee"} for r in same]

    def verdict(base: list[dict]) -> str:
        cells = {"u": {"dual": dual, "iql": base}}
        row = learning_pairs.baseline_pairs_table(cells, ["u"], baselines=["iql"])
        return row.splitlines()[-1].rsplit(" | ", 1)[1].removesuffix(" |")

    assert verdict(same) == "yes"
    assert verdict(moved) == "no: 2 hosts"
    assert verdict(edited) == "no: 2 commits, dirty tree"
    assert verdict(older) == "no: host not recorded"
