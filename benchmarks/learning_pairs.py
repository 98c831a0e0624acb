"""DUAL against its base critic, per cell of the learning suite: the paper's Table 2
comparison (IQL, Cal-QL, SO2 + OFF2ON, each with and without DUAL on top).

Each pair is compared on the seeds both variants ran, which share their data and
environment seeds: the table gives both means ± 95 % t intervals and the *paired*
difference (DUAL minus the base, seed by seed) with its own 95 % t interval, whose sign
is only read as a result when the interval excludes 0.

    >>> cells = {"c": {
    ...     "dual": [{"seed": s, "final_score": v} for s, v in enumerate([50.0, 60.0, 55.0])],
    ...     "iql": [{"seed": s, "final_score": v} for s, v in enumerate([40.0, 52.0, 44.0])]}}
    >>> print(critic_pairs_table(cells, ["c"]).splitlines()[-1])
    | c | IQL | 3 | 45.3 ± 15.2 | 55.0 ± 12.4 | +9.7 ± 3.8 ▲ |
"""

from __future__ import annotations

from collections.abc import Sequence

from learning_report import fmt, t_interval

CRITIC_PAIRS: tuple[tuple[str, str, str], ...] = (
    ("IQL", "iql", "dual"),
    ("Cal-QL", "calql", "dual_calql"),
    ("SO2 + OFF2ON", "so2", "dual_so2"),
)
"""(critic, base variant, DUAL-on-that-critic variant) of the learning suite."""


def paired_difference(dual: list[dict], base: list[dict], key: str = "final_score"):
    """``(n, mean ± half-width of DUAL − base over the seeds both ran, marker)``; the
    marker is ▲ / ▼ when the interval excludes 0, ≈ when it holds 0, ? for n < 2."""
    by_seed = {r["seed"]: r[key] for r in base}
    diffs = [r[key] - by_seed[r["seed"]] for r in dual if r["seed"] in by_seed]
    if not diffs:
        return 0, None, ""
    mean, half = t_interval(diffs)
    if len(diffs) < 2:
        return len(diffs), (mean, half), "?"
    marker = "▲" if mean - half > 0 else "▼" if mean + half < 0 else "≈"
    return len(diffs), (mean, half), marker


def critic_pairs_table(cells: dict[str, dict[str, list[dict]]], order: Sequence[str]) -> str:
    """Markdown rows ``cell | critic | n | base final | DUAL final | paired DUAL − base``
    for every pair of :data:`CRITIC_PAIRS` that a cell has both sides of."""
    lines = [
        "| cell | critic | n (paired) | base: final | DUAL on it: final | DUAL − base (paired) |",
        "|---|---|---:|---|---|---|",
    ]
    for cell in sorted(cells, key=lambda c: order.index(c) if c in order else len(order)):
        variants = cells[cell]
        for critic, base, dual in CRITIC_PAIRS:
            if not variants.get(base) or not variants.get(dual):
                continue
            n, diff, marker = paired_difference(variants[dual], variants[base])
            if diff is None:
                continue
            seeds = {r["seed"] for r in variants[dual]} & {r["seed"] for r in variants[base]}
            finals = [
                fmt(t_interval([r["final_score"] for r in variants[v] if r["seed"] in seeds]))
                for v in (base, dual)
            ]
            mean, half = diff
            text = f"{mean:+.1f}" if n < 2 else f"{mean:+.1f} ± {half:.1f}"
            lines.append(
                f"| {cell} | {critic} | {n} | {finals[0]} | {finals[1]} | {text} {marker} |"
            )
    return "\n".join(lines)
