"""PNGs of the learning suite: learning curves per cell and action latency vs score.

Both read the compact per-run results of ``python -m benchmarks.learning`` (see
``benchmarks/learning/report.py``); matplotlib runs with the Agg backend.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

from benchmarks.learning.stats import t_interval

# Variant -> candidate of ``benchmarks/speed/latency.py --json`` that times its acting policy;
# a variant whose own name is a key of the latency JSON uses that entry instead.
LATENCY_CANDIDATE = {
    "dual": "dual_m5",
    "dual_lambda0": "dual_m5",  # λ = 0 changes the noise's variance, not the pass
    "dual_no_uq": "dual_m5",  # M = 0: the same trunk pass, the MAP head alone
    "dual_no_planner": "dual_m5",  # actor.init=scratch: the same network, untrained start
    "dual_no_distillation": "dual_m5_n8",
    "dual_latent_uq": "dual_m5_latent",
    "iql": "iql_actor",
    "iql_la": "iql_la_m5",
    "diffql": "diffql_n5",
    "diffql_la": "diffql_la_m5",
    "diffuser": "planner_n32",
    "dacer": "dacer_n5",
}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def curve_band(
    results: Sequence[dict], series: str = "history", value: str = "normalized_score"
) -> tuple[list[int], list[float], list[float]]:
    """Frames present in every run's ``series`` (the evaluations, or ``"online_signals"``),
    the mean of ``value`` there and the 95 % t half-width (0 with one run)."""
    common = set.intersection(*({h["frames"] for h in r[series]} for r in results))
    frames = sorted(common)
    means, halves = [], []
    for f in frames:
        values = [next(h[value] for h in r[series] if h["frames"] == f) for r in results]
        mean, half = t_interval(values)
        means.append(mean)
        halves.append(0.0 if math.isnan(half) else half)
    return frames, means, halves


def _signal_runs(results: Sequence[dict], name: str) -> list[dict]:
    """The runs that logged online signal ``name`` (JSONs from before the signals were
    kept have none)."""
    return [r for r in results if any(name in h for h in r.get("online_signals", []))]


def plot_cell_curves(variants: dict[str, list[dict]], path: Path, *, title: str) -> Path:
    """Mean normalized score ± 95 % t band per variant against online frames; below it, one
    panel per online signal that some variant's runs logged (DUAL's epistemic std and shift
    distance ``d_t`` per collected batch, :data:`torchrl_dual.recipe.o2o.plots.ONLINE_SIGNALS`),
    averaged over those runs."""
    from torchrl_dual.recipe.o2o.plots import ONLINE_SIGNALS

    plt = _pyplot()
    signals = [
        name
        for name in ONLINE_SIGNALS
        if any(_signal_runs(results, name) for results in variants.values())
    ]
    fig, axes = plt.subplots(
        1 + len(signals), 1, figsize=(6.5, 4 + 2 * len(signals)), sharex=True, squeeze=False
    )
    panels = [(axes[0, 0], "history", "normalized_score", "normalized score")]
    panels += [
        (axes[1 + i, 0], "online_signals", name, ONLINE_SIGNALS[name])
        for i, name in enumerate(signals)
    ]
    for ax, series, value, label in panels:
        for color, (variant, results) in enumerate(variants.items()):
            runs = results if series == "history" else _signal_runs(results, value)
            if not runs:
                continue
            frames, means, halves = curve_band(runs, series, value)
            ax.plot(
                frames, means, marker="o", markersize=3, color=f"C{color}",
                label=f"{variant} (n={len(runs)})",
            )  # fmt: skip
            ax.fill_between(
                frames,
                [m - h for m, h in zip(means, halves, strict=True)],
                [m + h for m, h in zip(means, halves, strict=True)],
                alpha=0.2,
                color=f"C{color}",
            )
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[-1, 0].set_xlabel("online environment frames (0 = end of the offline phase)")
    axes[0, 0].set_title(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def latency_points(variants: dict[str, list[dict]], latency_ms: dict[str, float]) -> list[tuple]:
    """(variant, candidate, latency ms, final-score mean, half-width) for each variant whose
    acting policy has a latency entry."""
    points = []
    for variant, results in variants.items():
        candidate = variant if variant in latency_ms else LATENCY_CANDIDATE.get(variant)
        if candidate in latency_ms:
            mean, half = t_interval([r["final_score"] for r in results])
            points.append((variant, candidate, latency_ms[candidate], mean, half))
    return points


def plot_latency_vs_score(points: list[tuple], path: Path, *, title: str) -> Path:
    """Batch-1 action latency (log x) against the final score mean ± 95 % t interval."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 4))
    for variant, candidate, ms, mean, half in points:
        ax.errorbar(ms, mean, yerr=0 if math.isnan(half) else half, fmt="o", capsize=4)
        ax.annotate(f"{variant}\n({candidate})", (ms, mean), fontsize=7, xytext=(5, 5),
                    textcoords="offset points")  # fmt: skip
    ax.set_xscale("log")
    ax.xaxis.set_minor_formatter(plt.NullFormatter())
    ax.margins(x=0.35, y=0.15)
    ax.set_xlabel("batch-1 action latency (ms, benchmarks/speed/latency.py)")
    ax.set_ylabel("final normalized score")
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
