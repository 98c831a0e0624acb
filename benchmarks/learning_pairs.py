"""Paired comparisons of the learning suite: DUAL against every baseline (the paper's
Table 1 claim), DUAL against its base critic, per cell (the paper's Table 2: IQL, Cal-QL,
SO2 + OFF2ON, each with and without DUAL on top), and DUAL's variants (ablations and
settings) against DUAL, on its offline phase where they share it.

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

from collections.abc import Iterable, Iterator, Mapping, Sequence

from learning_grid import baseline_variants, dual_variants
from learning_stats import fmt, t_interval

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


def _pair_cells(minuend: list[dict], subtrahend: list[dict]) -> tuple[int, list[str]] | None:
    """``(n, [subtrahend final, minuend final, paired final difference, paired AUC
    difference])`` as table cells, on the seeds both ran; ``None`` without a pair."""
    n, final, marker = paired_difference(minuend, subtrahend)
    if final is None:
        return None
    _, auc, auc_marker = paired_difference(minuend, subtrahend, key="auc")
    seeds = {r["seed"] for r in minuend} & {r["seed"] for r in subtrahend}
    finals = [
        fmt(t_interval([r["final_score"] for r in side if r["seed"] in seeds]))
        for side in (subtrahend, minuend)
    ]
    texts = [f"{m:+.1f}" if n < 2 else f"{m:+.1f} ± {h:.1f}" for m, h in (final, auc)]
    return n, [*finals, f"{texts[0]} {marker}", f"{texts[1]} {auc_marker}"]


def _against_dual(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    dual_from: dict[str, str],
    names: Iterable[str],
) -> Iterator[tuple[str, str, str, list[dict], list[dict]]]:
    """``(cell, reference cell, name, runs, reference dual runs)`` for every run set of
    ``names`` a cell has, in cell order, when ``dual_from.get(cell, cell)`` ran ``dual``."""
    for cell in sorted(cells, key=lambda c: order.index(c) if c in order else len(order)):
        reference = dual_from.get(cell, cell)
        dual = cells.get(reference, {}).get("dual")
        for name in names:
            runs = cells[cell].get(name)
            if runs and dual:
                yield cell, reference, name, runs, dual


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


def _same_offline(variant: list[dict], dual: list[dict]) -> str:
    """``k/n``: on how many of the paired seeds both runs scored the same offline (they
    loaded one offline phase; a code change between the runs can make them differ)."""
    by_seed = {r["seed"]: r["offline_score"] for r in dual}
    paired = [r for r in variant if r["seed"] in by_seed]
    same = sum(abs(r["offline_score"] - by_seed[r["seed"]]) < 1e-9 for r in paired)
    return f"{same}/{len(paired)}"


def dual_variant_pairs_table(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    dual_from: dict[str, str] | None = None,
    variants: Mapping[str, str] | None = None,
) -> str:
    """Markdown rows ``cell | variant | n | same offline | DUAL final | variant final |
    paired final and AUC differences`` for every DUAL variant a cell ran (``variants``:
    name -> its overrides; default :func:`learning_grid.dual_variants`), against the
    ``dual`` runs of ``dual_from[cell]`` (default: the cell itself).

    Examples:
        >>> run = lambda s, off, fin: {"seed": s, "offline_score": off, "final_score": fin,
        ...                             "auc": fin}
        >>> cells = {"u": {"dual": [run(0, 9.0, 50.0), run(1, 8.0, 60.0)]},
        ...          "u_online": {"dual_utd025": [run(0, 9.0, 47.0), run(1, 7.0, 55.0)]}}
        >>> print(dual_variant_pairs_table(cells, ["u", "u_online"], {"u_online": "u"})
        ...       .splitlines()[-1])
        | u_online | `dual_utd025` (`online.utd_ratio=0.25`) | 2 | 1/2 | 55.0 ± 63.5 | 51.0 ± 50.8 | -4.0 ± 12.7 ≈ | -4.0 ± 12.7 ≈ |
    """
    dual_from = dual_from or {}
    variants = dual_variants() if variants is None else variants
    lines = [
        "| cell | variant | n (paired) | same offline phase | `dual`: final | variant: final "
        "| variant − `dual`: final | variant − `dual`: AUC |",
        "|---|---|---:|---:|---|---|---|---|",
    ]
    for cell, _, variant, runs, dual in _against_dual(cells, order, dual_from, variants):
        pair = _pair_cells(runs, dual)
        if pair is not None:
            n, values = pair
            lines.append(
                f"| {cell} | `{variant}` (`{variants[variant]}`) | {n} | "
                f"{_same_offline(runs, dual)} | " + " | ".join(values) + " |"
            )
    return "\n".join(lines)


def baseline_pairs_table(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    dual_from: dict[str, str] | None = None,
    baselines: Sequence[str] | None = None,
) -> str:
    """Markdown rows ``cell | baseline | n | DUAL's cell | baseline final | DUAL final |
    paired DUAL − baseline: final and AUC`` for every baseline run of a cell (default
    :func:`learning_grid.baseline_variants`) against the ``dual`` runs of
    ``dual_from[cell]`` (default: the cell itself), on the seeds both ran.

    Examples:
        >>> run = lambda s, fin: {"seed": s, "final_score": fin, "auc": fin / 2}
        >>> cells = {"u": {"dual": [run(0, 50.0), run(1, 60.0)]},
        ...          "u_base": {"edis": [run(0, 40.0), run(1, 45.0)]}}
        >>> print(baseline_pairs_table(cells, ["u", "u_base"], {"u_base": "u"}, ["edis"])
        ...       .splitlines()[-1])
        | u_base | `edis` | 2 | u | 42.5 ± 31.8 | 55.0 ± 63.5 | +12.5 ± 31.8 ≈ | +6.2 ± 15.9 ≈ |
    """
    dual_from = dual_from or {}
    baselines = baseline_variants() if baselines is None else baselines
    lines = [
        "| cell | baseline | n (paired) | `dual` of | baseline: final | `dual`: final "
        "| DUAL − baseline: final | DUAL − baseline: AUC |",
        "|---|---|---:|---|---|---|---|---|",
    ]
    for cell, reference, base, runs, dual in _against_dual(cells, order, dual_from, baselines):
        pair = _pair_cells(dual, runs)
        if pair is not None:
            n, values = pair
            lines.append(f"| {cell} | `{base}` | {n} | {reference} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def pairs_sections(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    dual_from: dict[str, str] | None = None,
) -> list[str]:
    """The report's paired comparisons, each a heading, what it measures and its table
    (those with no pair yet are left out)."""
    parts: list[str] = []
    sections = (
        (
            "DUAL against every baseline, seed by seed",
            "The paper's claim that DUAL beats IQL, Diff-QL (with and without LA), "
            "Diffuser, DACER and EDIS, on the suite's runs: each baseline against the "
            "`dual` runs of the same env settings (*`dual` of*: the cell they come from; "
            "a cell without its own `dual` uses the one its `Cell.reference` or its "
            "overrides name), on the seeds both ran, which share data and env seeds. "
            "*DUAL − baseline*: the mean of the per-seed differences ± its 95 % t "
            "half-width; ▲ / ▼ when that interval excludes 0, ≈ when it holds 0.",
            baseline_pairs_table(cells, order, dual_from),
        ),
        (
            "DUAL's variants against DUAL, seed by seed",
            "DUAL's ablations and settings run on `dual`'s data and env seeds, so their "
            "difference to `dual` is measured seed by seed: *variant − `dual`* is the "
            "mean of the per-seed differences ± its 95 % t half-width, ▲ / ▼ when that "
            "interval excludes 0, ≈ when it holds 0. Those that change only what the "
            "online phase reads also load `dual`'s offline phase (the suite's offline "
            "cache). *Same offline phase*: on how many of the paired seeds the two runs' "
            "offline scores are identical; the ablations that change the offline phase "
            "(no planner, no distillation) train their own (0/n), as does a run made "
            "after a code change that alters the offline computation, or on another "
            "CPU: such a pair also carries the offline phase's variance.",
            dual_variant_pairs_table(cells, order, dual_from),
        ),
        (
            "DUAL on each critic against the critic alone",
            "The paper's Table 2 comparison on the suite's runs: each base critic's own "
            "algorithm (`iql`, `calql`, `so2`) against DUAL on that critic (`dual`, "
            "`dual_calql`, `dual_so2`), on the seeds both ran (same data and env seeds). "
            "*DUAL − base*: the mean of the per-seed differences ± its 95 % t half-width; "
            "▲ / ▼ when that interval excludes 0, ≈ when it holds 0 (inside the noise).",
            critic_pairs_table(cells, order),
        ),
    )
    for title, about, table in sections:
        if table.count("\n") > 1:
            parts += [f"### {title}", about, table]
    return parts
