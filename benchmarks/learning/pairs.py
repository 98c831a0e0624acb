"""Paired comparisons of the learning suite: DUAL against every baseline (the paper's
Table 1 claim), DUAL's variants (ablations and settings) against DUAL, on its offline phase
where they share it, and each baseline against its reference implementation.

Each pair is compared on the seeds both variants ran, which share their data and
environment seeds: the table gives both means ± 95 % t intervals and the *paired*
difference (DUAL minus the base, seed by seed) with its own 95 % t interval, whose sign
is only read as a result when the interval excludes 0, and the equivalence test of that
difference (:func:`benchmarks.learning.stats.equivalence`: its 90 % interval inside ±10 points, TOST
at α = 0.05), which is what "level" or "at full strength" needs.

    >>> dual = [{"seed": s, "final_score": v} for s, v in enumerate([50.0, 60.0, 55.0])]
    >>> iql = [{"seed": s, "final_score": v} for s, v in enumerate([40.0, 52.0, 44.0])]
    >>> n, (mean, half), marker = paired_difference(dual, iql)
    >>> n, round(mean, 1), round(half, 1), marker, paired_equivalence(dual, iql).text()
    (3, 9.7, 3.8, '▲', 'no [+7.1, +12.2]')
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence

from benchmarks.learning.stats import (
    EQUIVALENCE_MARGIN,
    Equivalence,
    equivalence,
    fmt,
    t_interval,
    t_quantile,
)
from benchmarks.learning.variants import (
    REFERENCE_SCRIPTS,
    VARIANTS,
    baseline_variants,
    dual_variants,
)
from benchmarks.provenance import crossing

_WITHIN = f"equivalent within ±{EQUIVALENCE_MARGIN:g}? (90 % interval)"
"""The header of the equivalence columns (:func:`paired_equivalence`)."""
_ONE_SITTING = "one host, one commit?"
"""The header of the provenance column (:func:`same_host_and_commit`)."""

EQUIVALENCE_ABOUT = (
    "Every paired table of this section gives, next to the paired difference and its 95 % "
    "interval "
    "(▲ / ▼: a difference is shown), an **equivalence test** (TOST: two one-sided t tests "
    "at α = 0.05) of the same per-seed differences: *yes* when their 90 % t interval, in "
    f"brackets, lies inside ±{EQUIVALENCE_MARGIN:g} normalized points, i.e. the two are shown "
    f"to be within {EQUIVALENCE_MARGIN:g} points of each other; *no* when it reaches past "
    f"±{EQUIVALENCE_MARGIN:g}: equivalence is not shown (which does not show a difference "
    "either); ? with fewer than 2 seeds. Only a *yes* supports calling two methods level "
    f"or tied. Why ±{EQUIVALENCE_MARGIN:g}: the normalized score "
    "runs from a random policy (0) to the expert (100), so it is a tenth of that range, and "
    "about one seed-to-seed standard deviation of one method's final score on U-maze at this "
    "budget (5-10 points over 5 seeds): a smaller gap would not tell two methods from two "
    "seeds of one. It is fixed once for every claim, not chosen per claim. With 3-5 seeds the "
    "test is demanding: even at a mean difference of 0 the 90 % "
    f"interval fits inside ±{EQUIVALENCE_MARGIN:g} only when the per-seed differences' "
    f"standard deviation is below {EQUIVALENCE_MARGIN:g} √n / t(0.95, n − 1): "
    + ", ".join(
        f"{EQUIVALENCE_MARGIN * n**0.5 / t_quantile(0.95, n - 1):.1f} at n = {n}" for n in (5, 3)
    )
    + ". *One host, one commit?*: *yes* when every paired run recorded the same host id and "
    "commit with a clean tree (`benchmarks/provenance/`); *no* names what crosses (hosts, "
    "commits, a dirty tree; runs written before the host id was recorded say *host not "
    "recorded*): such a pair also carries the difference between hosts or code versions."
)
"""The report's paragraph on the equivalence columns: the margin, stated and justified once."""


def _differences(minuend: list[dict], subtrahend: list[dict], key: str) -> list[float]:
    """``minuend − subtrahend`` of ``key``, seed by seed, over the seeds both ran."""
    by_seed = {r["seed"]: r[key] for r in subtrahend}
    return [r[key] - by_seed[r["seed"]] for r in minuend if r["seed"] in by_seed]


def paired_difference(dual: list[dict], base: list[dict], key: str = "final_score"):
    """``(n, mean ± half-width of DUAL − base over the seeds both ran, marker)``; the
    marker is ▲ / ▼ when the interval excludes 0, ≈ when it holds 0, ? for n < 2."""
    diffs = _differences(dual, base, key)
    if not diffs:
        return 0, None, ""
    mean, half = t_interval(diffs)
    if len(diffs) < 2:
        return len(diffs), (mean, half), "?"
    marker = "▲" if mean - half > 0 else "▼" if mean + half < 0 else "≈"
    return len(diffs), (mean, half), marker


def paired_equivalence(
    minuend: list[dict], subtrahend: list[dict], key: str = "final_score"
) -> Equivalence:
    """:func:`benchmarks.learning.stats.equivalence` of ``minuend − subtrahend`` seed by seed (the
    seeds both ran), at the report's margin :data:`benchmarks.learning.stats.EQUIVALENCE_MARGIN`."""
    return equivalence(_differences(minuend, subtrahend, key), EQUIVALENCE_MARGIN)


def same_host_and_commit(*sides: list[dict]) -> str:
    """``yes`` when every run of ``sides`` (the paired runs) recorded one host id and one
    commit, none dirty (:func:`benchmarks.provenance.crossing`); else ``no: `` and what
    crosses (runs written before the host was recorded: ``host not recorded``).

    Examples:
        >>> run = lambda host: {"provenance": {"host": host, "commit": "c", "dirty": False}}
        >>> same_host_and_commit([run("a")], [run("a")]), same_host_and_commit([run("a")], [run("b")])
        ('yes', 'no: 2 hosts')
    """
    crosses = crossing(r for side in sides for r in side)
    return f"no: {crosses}" if crosses else "yes"


def _pair_cells(
    minuend: list[dict], subtrahend: list[dict], keys: Sequence[str] = ("final_score", "auc")
) -> tuple[int, list[str]] | None:
    """``(n, [subtrahend final, minuend final, one paired difference per key, the
    equivalence verdicts of the keys joined by " / ", whether the paired runs share one host
    and commit])`` as table cells, on the seeds both ran; ``None`` without a pair."""
    n, _, _ = paired_difference(minuend, subtrahend, keys[0])
    if not n:
        return None
    seeds = {r["seed"] for r in minuend} & {r["seed"] for r in subtrahend}
    finals = [
        fmt(t_interval([r["final_score"] for r in side if r["seed"] in seeds]))
        for side in (subtrahend, minuend)
    ]
    texts = []
    for key in keys:
        _, (m, h), marker = paired_difference(minuend, subtrahend, key)
        texts.append(f"{m:+.1f} {marker}" if n < 2 else f"{m:+.1f} ± {h:.1f} {marker}")
    verdicts = " / ".join(paired_equivalence(minuend, subtrahend, key).text() for key in keys)
    paired = [[r for r in side if r["seed"] in seeds] for side in (minuend, subtrahend)]
    return n, [*finals, *texts, verdicts, same_host_and_commit(*paired)]


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
    paired final and AUC differences | their equivalence verdicts`` for every DUAL variant a cell ran (``variants``:
    name -> its overrides; default :func:`benchmarks.learning.variants.dual_variants`), against the
    ``dual`` runs of ``dual_from[cell]`` (default: the cell itself).

    Examples:
        >>> run = lambda s, off, fin: {"seed": s, "offline_score": off, "final_score": fin,
        ...                             "auc": fin}
        >>> cells = {"u": {"dual": [run(0, 9.0, 50.0), run(1, 8.0, 60.0)]},
        ...          "u_online": {"dual_utd025": [run(0, 9.0, 47.0), run(1, 7.0, 55.0)]}}
        >>> print(dual_variant_pairs_table(cells, ["u", "u_online"], {"u_online": "u"})
        ...       .splitlines()[-1])
        | u_online | `dual_utd025` (`online.utd_ratio=0.25`) | 2 | 1/2 | 55.0 ± 63.5 | 51.0 ± 50.8 | -4.0 ± 12.7 ≈ | -4.0 ± 12.7 ≈ | no [-10.3, +2.3] / no [-10.3, +2.3] | no: host not recorded, commit not recorded |
    """
    dual_from = dual_from or {}
    variants = dual_variants() if variants is None else variants
    lines = [
        "| cell | variant | n (paired) | same offline phase | `dual`: final | variant: final "
        f"| variant − `dual`: final | variant − `dual`: AUC | {_WITHIN}: final / AUC "
        f"| {_ONE_SITTING} |",
        "|---|---|---:|---:|---|---|---|---|---|---|",
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
    dual_runs: dict[str, tuple[str, str]] | None = None,
) -> str:
    """Markdown rows ``cell | baseline | n | DUAL's cell | baseline final | DUAL final |
    paired DUAL − baseline: final and AUC | their equivalence verdicts`` for every baseline run of a cell (default
    :func:`benchmarks.learning.variants.baseline_variants`) against the ``dual`` runs of
    ``dual_from[cell]`` (default: the cell itself), or against the ``(cell, variant)`` runs
    ``dual_runs`` names for it (:func:`benchmarks.learning.cells.baseline_duals`), on the
    seeds both ran.

    Examples:
        >>> run = lambda s, fin: {"seed": s, "final_score": fin, "auc": fin / 2}
        >>> cells = {"u": {"dual": [run(0, 50.0), run(1, 60.0)]},
        ...          "u_base": {"edis": [run(0, 40.0), run(1, 45.0)]}}
        >>> print(baseline_pairs_table(cells, ["u", "u_base"], {"u_base": "u"}, ["edis"])
        ...       .splitlines()[-1])
        | u_base | `edis` | 2 | u | 42.5 ± 31.8 | 55.0 ± 63.5 | +12.5 ± 31.8 ≈ | +6.2 ± 15.9 ≈ | no [-3.3, +28.3] / no [-1.6, +14.1] | no: host not recorded, commit not recorded |
    """
    dual_from = dual_from or {}
    baselines = baseline_variants() if baselines is None else baselines
    lines = [
        "| cell | baseline | n (paired) | `dual` of | baseline: final | `dual`: final "
        f"| DUAL − baseline: final | DUAL − baseline: AUC | {_WITHIN}: final / AUC "
        f"| {_ONE_SITTING} |",
        "|---|---|---:|---|---|---|---|---|---|---|",
    ]
    dual_runs = dual_runs or {}
    for cell, reference, base, runs, dual in _against_dual(cells, order, dual_from, baselines):
        source = reference
        if cell in dual_runs:
            reference, variant = dual_runs[cell]
            dual = cells.get(reference, {}).get(variant, [])
            source = reference if variant == "dual" else f"{reference} (`{variant}`)"
        pair = _pair_cells(dual, runs)
        if pair is not None:
            n, values = pair
            lines.append(f"| {cell} | `{base}` | {n} | {source} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def reference_pairs() -> dict[str, str]:
    """The suite's own variant of each method that a reference implementation also ran
    (:data:`benchmarks.learning.variants.REFERENCE_SCRIPTS`) -> that reference variant: ours is the
    variant with the very same overrides (the same run on the other implementation),
    ``<ours>_d3rlpy[_suffix]``'s name breaking a tie.

        >>> pairs = reference_pairs()
        >>> pairs["iql"], pairs["calql"], pairs["calql_sparse_no_bound"]
        ('iql_d3rlpy', 'calql_d3rlpy', 'calql_d3rlpy_sparse')
        >>> "calql_sparse" in pairs  # its sparse bound has no d3rlpy counterpart
        False
    """
    pairs = {}
    for ref in REFERENCE_SCRIPTS:
        same = [
            name
            for name, overrides in VARIANTS.items()
            if overrides == VARIANTS[ref] and name not in REFERENCE_SCRIPTS
        ]
        named = ref.replace("_d3rlpy", "", 1)
        if same:
            pairs[named if named in same else same[0]] = ref
    return pairs


def reference_pairs_table(cells: dict[str, dict[str, list[dict]]], order: Sequence[str]) -> str:
    """Markdown rows ``cell | ours | reference | n | reference final | ours final | paired
    ours − reference: offline, final, AUC | their equivalence verdicts`` for every pair of
    :func:`reference_pairs` that a cell ran both sides of.

    Examples:
        >>> run = lambda s, fin: {"seed": s, "offline_score": 10.0, "final_score": fin,
        ...                       "auc": fin}
        >>> cells = {"u": {"iql": [run(0, 50.0), run(1, 52.0), run(2, 51.0)],
        ...                "iql_d3rlpy": [run(0, 49.0), run(1, 50.0), run(2, 51.0)]}}
        >>> print(reference_pairs_table(cells, ["u"]).splitlines()[-1])
        | u | `iql` | `iql_d3rlpy` | 3 | 50.0 ± 2.5 | 51.0 ± 2.5 | +0.0 ± 0.0 ≈ | +1.0 ± 2.5 ≈ | +1.0 ± 2.5 ≈ | yes [+0.0, +0.0] / yes [-0.7, +2.7] / yes [-0.7, +2.7] | no: host not recorded, commit not recorded |
    """
    lines = [
        "| cell | ours | reference | n (paired) | reference: final | ours: final "
        "| ours − reference: offline | ours − reference: final | ours − reference: AUC "
        f"| {_WITHIN}: offline / final / AUC | {_ONE_SITTING} |",
        "|---|---|---|---:|---|---|---|---|---|---|---|",
    ]
    keys = ("offline_score", "final_score", "auc")
    for cell in sorted(cells, key=lambda c: order.index(c) if c in order else len(order)):
        for ours, ref in reference_pairs().items():
            pair = _pair_cells(cells[cell].get(ours, []), cells[cell].get(ref, []), keys)
            if pair is not None:
                n, values = pair
                lines.append(f"| {cell} | `{ours}` | `{ref}` | {n} | " + " | ".join(values) + " |")
    return "\n".join(lines)


def pairs_sections(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    dual_from: dict[str, str] | None = None,
    dual_runs: dict[str, tuple[str, str]] | None = None,
) -> list[str]:
    """The report's paired comparisons, each a heading, what it measures and its table
    (those with no pair yet are left out); the equivalence test they use is explained once,
    above them (:data:`EQUIVALENCE_ABOUT`, in the report's claims)."""
    parts: list[str] = []
    sections = (
        (
            "DUAL against every baseline, seed by seed",
            "The paper's claim that DUAL beats IQL, Diff-QL (with and without LA), "
            "Diffuser, DACER and EDIS, on the suite's runs: each baseline against the "
            "`dual` runs of the same env settings (*`dual` of*: the cell they come from; "
            "a cell without its own `dual` uses the one its `Cell.reference` or its "
            "overrides name; a cell whose baselines change the reward pairs them with its "
            "own DUAL under the same change, named in brackets), on the seeds both ran, "
            "which share data and env seeds. "
            "*DUAL − baseline*: the mean of the per-seed differences ± its 95 % t "
            "half-width; ▲ / ▼ when that interval excludes 0, ≈ when it holds 0.",
            baseline_pairs_table(cells, order, dual_from, dual_runs=dual_runs),
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
            "Baselines against their reference implementations, seed by seed",
            "Each method that a reference implementation also ran (d3rlpy 2.8.1's, "
            "`benchmarks/learning/reference_d3rlpy.py`, as a learner of the same run: same data, "
            "budget, replay and evaluator) against it, on the seeds both ran: *ours − "
            "reference* is the mean of the per-seed differences ± its 95 % t half-width, "
            "▲ / ▼ when that interval excludes 0, ≈ when it holds 0. A baseline at full "
            "strength needs ours not to be worse than the reference by more than the margin: "
            "the lower end of the bracket above its negative (the one-sided half of the "
            "equivalence test); *yes* also bounds it from above.",
            reference_pairs_table(cells, order),
        ),
    )
    for title, about, table in sections:
        if table.count("\n") > 1:
            parts += [f"### {title}", about, table]
    return parts
