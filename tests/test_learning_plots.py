"""``benchmarks/learning/plots.py`` and the online signals of the suite's per-run JSONs."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from benchmarks.learning import plots as lp
from benchmarks.learning import report as lr

REPO = Path(__file__).resolve().parents[1]


def _summary(seed: int, shift_distance: list[float] | None) -> dict:
    """A recipe ``summary.json`` with evaluations at 0 and 100 frames and, unless ``None``,
    one online-signal record per 50-frame batch."""
    summary = {
        "algo": "dual", "env": "pointmaze_umaze", "seed": seed, "budget": "smoke",
        "history": [
            {"label": label, "frames": f, "normalized_score": 10.0 * (seed + 1) + f / 10,
             "return": 0.0}
            for label, f in (("offline", 0), ("online", 100))
        ],
        "offline_seconds": 10.0, "wall_seconds": 20.0,
    }  # fmt: skip
    if shift_distance is not None:
        summary["online_signals"] = [
            {"frames": 50 * (i + 1), "epistemic_std": 0.1, "shift_distance": d}
            for i, d in enumerate(shift_distance)
        ]
    return summary


def _compact(seed: int, shift_distance: list[float] | None, variant: str = "dual") -> dict:
    meta = {"commit": "abc", "date": "today", "machine": "test box"}
    summary = _summary(seed, shift_distance)
    return lr.compact_result(summary, variant=variant, cell="umaze", overrides=[], meta=meta)


def _png_height(path: Path) -> int:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", data[16:24])[1]


def test_compact_results_keep_the_online_signals_and_older_summaries_have_none():
    result = _compact(0, [0.123456789, 2.0])
    assert result["online_signals"] == [
        {"frames": 50, "epistemic_std": 0.1, "shift_distance": 0.123457},
        {"frames": 100, "epistemic_std": 0.1, "shift_distance": 2.0},
    ]
    assert _compact(0, None)["online_signals"] == []


def test_signal_band_is_the_mean_and_t_interval_over_the_runs_that_logged_it():
    runs = [_compact(0, [1.0, 3.0]), _compact(1, [3.0, 5.0]), _compact(2, None)]
    logged = lp._signal_runs(runs, "shift_distance")
    assert [r["seed"] for r in logged] == [0, 1]
    frames, means, halves = lp.curve_band(logged, "online_signals", "shift_distance")
    assert (frames, means) == ([50, 100], [2.0, 4.0])
    assert halves == pytest.approx([12.7062 * 1.0] * 2, rel=1e-4)  # t(1) · s / sqrt(2), s = √2
    # the score band still reads the evaluations
    assert lp.curve_band(runs)[1] == [20.0, 30.0]


def test_cell_plot_adds_a_panel_per_logged_signal(tmp_path):
    with_signals = {"dual": [_compact(0, [1.0, 2.0])], "iql": [_compact(0, None, "iql")]}
    without = {"iql": [_compact(0, None, "iql")]}
    tall = lp.plot_cell_curves(with_signals, tmp_path / "a.png", title="signals")
    short = lp.plot_cell_curves(without, tmp_path / "b.png", title="score only")
    # 110 dpi: 4 inches for the score, 2 more per signal panel (epistemic std, d_t)
    assert (_png_height(short), _png_height(tall)) == (440, 880)
