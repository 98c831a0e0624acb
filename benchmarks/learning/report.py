"""Statistics and the generated report of the learning suite (``python -m benchmarks.learning``).

Pure functions over the compact per-run JSONs that the suite writes under
``benchmarks/results/<budget>/<cell>/<variant>/seed<k>.json``: 95 % Student-t intervals,
the interval-overlap marker, the area under the online curve, the score at a given
wall-clock or CPU time, the markdown section between the ``learning-suite`` markers of
``docs/results.md``, and its PNGs (``benchmarks/learning/plots.py``).

    >>> mean, half = t_interval([1.0, 2.0, 3.0])  # sd 1, n 3: t(0.975, 2) / sqrt(3)
    >>> round(mean, 3), round(half, 3)
    (2.0, 2.484)
    >>> separation((10.0, 1.0), (5.0, 1.0))
    '▲'
    >>> online_auc([{"frames": 0, "normalized_score": 0.0}, {"frames": 10, "normalized_score": 10.0}])
    5.0
"""

from __future__ import annotations

import json
import math
import re
import statistics
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from benchmarks.learning.claims import claims_table, seeds_text
from benchmarks.learning.equal_time import (  # noqa: F401 - re-exported
    clock_of,
    equal_compute_table,
    eval_times,
    run_seconds,
    score_at_time,
)
from benchmarks.learning.pairs import EQUIVALENCE_ABOUT, pairs_sections
from benchmarks.learning.stats import fmt, t_interval, t_quantile_975  # noqa: F401 - re-exported
from benchmarks.provenance import record_of


def markers(budget: str) -> tuple[str, str]:
    """The begin and end markers of one budget's generated section: each budget's suite
    has its own section, so regenerating one leaves the others as they are."""
    return f"<!-- learning-suite:{budget}:begin -->", f"<!-- learning-suite:{budget}:end -->"


def separation(a: tuple[float, float], b: tuple[float, float]) -> str:
    """``'▲'`` if interval ``a`` (mean, half) lies above ``b``, ``'▼'`` below, ``'≈'`` if
    they overlap, ``'?'`` without an interval. Non-overlap of two 95 % intervals is a
    conservative test: it implies a significant difference, not conversely."""
    (ma, ha), (mb, hb) = a, b
    if math.isnan(ha) or math.isnan(hb):
        return "?"
    if ma - ha > mb + hb:
        return "▲"
    if ma + ha < mb - hb:
        return "▼"
    return "≈"


def online_auc(history: Sequence[dict]) -> float:
    """Trapezoid mean of the normalized score over online frames, from the offline point
    (frames 0) to the last evaluation: area / last frame (the score itself if one point)."""
    frames = [float(h["frames"]) for h in history]
    scores = [float(h["normalized_score"]) for h in history]
    if len(frames) == 1 or frames[-1] <= frames[0]:
        return scores[-1]
    area = sum(
        (frames[i + 1] - frames[i]) * (scores[i + 1] + scores[i]) / 2
        for i in range(len(frames) - 1)
    )
    return area / (frames[-1] - frames[0])


def compact_result(summary: dict, *, variant: str, cell: str, overrides: list[str], meta: dict):
    """The committed JSON of one run, from the recipe's ``summary.json``."""
    keep = ("label", "frames", "normalized_score", "return", "normalized_score_unshifted")
    history = [{k: h[k] for k in keep if k in h} for h in summary["history"]]
    online = [h for h in history if h["label"] == "online"]
    offline = next((h for h in history if h["label"] == "offline"), history[0])
    return {
        "variant": variant,
        "cell": cell,
        "seed": summary["seed"],
        "budget": summary["budget"],
        "algo": summary["algo"],
        "env": summary["env"],
        "shift": summary.get("shift", "none"),
        "overrides": overrides,
        "history": history,
        "offline_score": offline["normalized_score"],
        "final_score": (online or history)[-1]["normalized_score"],
        "auc": online_auc([offline, *online]),
        "offline_seconds": summary["offline_seconds"],
        "online_seconds": summary["wall_seconds"] - summary["offline_seconds"],
        "wall_seconds": summary["wall_seconds"],
        "stage_seconds": summary.get("stage_seconds", {}),
        # CPU seconds of the run's process (absent in summaries written before they were)
        "offline_cpu_seconds": _offline_cpu(summary),
        "cpu_seconds": summary.get("cpu_seconds"),
        "stage_cpu_seconds": summary.get("stage_cpu_seconds", {}),
        "shared_offline": summary.get("shared_offline", False),
        # DUAL's epistemic std and d_t per collected batch (absent before they were kept)
        "online_signals": [
            {k: round(v, 6) if isinstance(v, float) else v for k, v in signals.items()}
            for signals in summary.get("online_signals", [])
        ],
        **meta,
    }


def _offline_cpu(summary: dict) -> float | None:
    stages = summary.get("stage_cpu_seconds")
    if not stages:
        return None
    return round(sum(v for k, v in stages.items() if k != "online"), 3)


def load_results(root: Path) -> dict[str, dict[str, list[dict]]]:
    """``root/<cell>/<variant>/seed*.json`` -> {cell: {variant: [result, ...]}} (by seed)."""
    out: dict[str, dict[str, list[dict]]] = {}
    for path in sorted(Path(root).glob("*/*/seed*.json")):
        result = json.loads(path.read_text())
        out.setdefault(path.parent.parent.name, {}).setdefault(path.parent.name, []).append(result)
    for variants in out.values():
        for results in variants.values():
            results.sort(key=lambda r: r["seed"])
    return out


def _offline_unshifted(result: dict) -> float:
    """The offline policy's score without the cell's shift (NaN if not recorded)."""
    offline = next((h for h in result["history"] if h["label"] == "offline"), {})
    return float(offline.get("normalized_score_unshifted", math.nan))


def epistemic_share(result: dict) -> float | None:
    """The run's mean over its collected batches of the epistemic share of the executed
    variance (``online/epistemic_share``: Eq. 9's ``Var_m`` over ``σ̄² + Var_m + v_c + λ d``);
    ``None`` for a run without an ensemble or from before the share was logged."""
    values = [
        s["epistemic_share"]
        for s in result.get("online_signals") or []
        if s.get("epistemic_share") is not None
    ]
    return statistics.fmean(values) if values else None


def epistemic_share_bound(result: dict) -> float | None:
    """For a run that logged ``epistemic_std`` and ``exploration_std`` per batch but not the
    share (the suite's earlier runs): the mean over batches of ``epistemic_std² /
    exploration_std²``, an upper bound of :func:`epistemic_share`'s value (the share divides
    by the batch's mean executed variance, ``exploration_std`` is its mean executed std,
    and a mean's square is at most the mean of the squares); ``None`` without both."""
    values = [
        s["epistemic_std"] ** 2 / s["exploration_std"] ** 2
        for s in result.get("online_signals") or []
        if s.get("epistemic_std") is not None and s.get("exploration_std")
    ]
    return statistics.fmean(values) if values else None


def share_text(results: Sequence[dict]) -> str:
    """The table's epistemic share of ``results`` (one variant's runs): mean ± t half-width
    in percent; "≤ x %" (the mean of the runs' shares, or of their bounds where a run
    logged only the stds) when some run has only a bound; "—" when some run has neither."""
    shares = [epistemic_share(r) for r in results]
    if None not in shares:
        return f"{fmt(t_interval([100 * x for x in shares]))} %"
    values = [
        x if x is not None else epistemic_share_bound(r)
        for x, r in zip(shares, results, strict=True)
    ]
    return "—" if None in values else f"≤ {100 * statistics.fmean(values):.1f} %"


def cell_table(variants: dict[str, list[dict]], order: Sequence[str]) -> str:
    """Markdown table of one cell: mean ± 95 % t half-width per variant, and which
    variants separate from ``dual`` (final score / AUC). Under an online shift it adds
    the offline policy's score without the shift (the shift's bite)."""
    shifted = any(r.get("shift", "none") != "none" for rs in variants.values() for r in rs)
    extra = " offline, no shift |" if shifted else ""
    lines = [
        f"| variant | n | seeds | offline score |{extra} final online score | AUC (online) "
        "| wall min | CPU min | epistemic share | vs dual: final / AUC | CPU · commit |",
        "|---|---:|---|---|" + ("---|" if shifted else "") + "---|---|---:|---:|---|---|---|",
    ]
    stats = {
        v: {k: t_interval([r[k] for r in rs]) for k in ("offline_score", "final_score", "auc")}
        for v, rs in variants.items()
    }
    for v in sorted(variants, key=lambda v: order.index(v) if v in order else len(order)):
        rs, s = variants[v], stats[v]
        if v == "dual" or "dual" not in stats:
            marker = "—"
        else:
            marker = " / ".join(separation(s[k], stats["dual"][k]) for k in ("final_score", "auc"))
        wall = statistics.fmean(r["wall_seconds"] for r in rs) / 60
        cpu = (
            f"{statistics.fmean(r['cpu_seconds'] for r in rs) / 60:.1f}"
            if clock_of(rs) == "cpu"
            else "—"
        )
        unshifted = ""
        if shifted:
            values = [_offline_unshifted(r) for r in rs]
            unshifted = " — |" if any(map(math.isnan, values)) else f" {fmt(t_interval(values))} |"
        share = share_text(rs)
        lines.append(
            f"| `{v}` | {len(rs)} | {seeds_text(r['seed'] for r in rs)} | "
            f"{fmt(s['offline_score'])} |{unshifted} {fmt(s['final_score'])} "
            f"| {fmt(s['auc'])} | {wall:.1f} | {cpu} | {share} | {marker} | {run_on(rs)} |"
        )
    return "\n".join(lines)


def run_on(results: Iterable[dict]) -> str:
    """Where ``results`` ran, from their JSONs: the CPU models and the commit (or how many
    commits), ``(dirty)`` when a tree was dirty.

    >>> run = lambda cpu, commit: {"commit": commit, "machine": f"Linux, 2 CPUs ({cpu}), torch"}
    >>> run_on([run("Intel(R) Xeon(R) Processor", "a")])
    'Intel Xeon · a'
    >>> run_on([run("AMD EPYC", "cb46f837b765")] * 2), run_on([run("Xeon", "a"), run("EPYC", "b")])
    ('AMD EPYC · cb46f83', 'EPYC + Xeon · 2 commits')
    """
    cpus, commits, dirty = set(), set(), False
    for result in results:
        record = record_of(result)
        named = re.search(r"CPUs \((.+?)\), ", result.get("machine", ""))
        cpu = (result.get("provenance") or {}).get("cpu") or (named[1] if named else "")
        cpus.add(cpu.replace("(R)", "").removesuffix(" Processor") or "?")
        commits.add(record.get("commit") or "?")
        dirty |= bool(record.get("dirty"))
    commit = next(iter(commits))[:7] if len(commits) == 1 else f"{len(commits)} commits"
    return f"{' + '.join(sorted(cpus))} · {commit}" + (" (dirty)" if dirty else "")


def hidden_text(
    cells: dict[str, dict[str, list[dict]]],
    retired: Mapping[str, str],
    superseded: Mapping[str, str],
) -> str:
    """The report's list of what its tables leave out: each retired cell and superseded
    variant that has runs, with its run count and why."""
    items = [
        f"* cell `{cell}` ({sum(map(len, cells[cell].values()))} runs): {why}"
        for cell, why in retired.items()
        if cell in cells
    ]
    for variant, why in superseded.items():
        count = sum(len(vs.get(variant, [])) for vs in cells.values())
        if count:
            items.append(f"* variant `{variant}` ({count} runs): {why}")
    return "\n".join(items)


def render_section(
    cells: dict[str, dict[str, list[dict]]],
    *,
    budget: str,
    header: str,
    cell_about: dict[str, str],
    variant_order: Sequence[str],
    figures: dict[str, str],
    command: str,
    results_dir: str,
    dual_from: dict[str, str] | None = None,
    dual_runs: dict[str, tuple[str, str]] | None = None,
    retired: Mapping[str, str] | None = None,
    superseded: Mapping[str, str] | None = None,
) -> str:
    """The markdown between the markers: the claims (:mod:`benchmarks.learning.claims`),
    ``header`` (what the cells are, how to run), one table per cell (in the order of
    ``cell_about``: name -> title), the equal-compute comparison, the paired comparisons
    (``dual_from``: cell -> the cell whose ``dual`` its DUAL variants pair with;
    ``dual_runs``: cell -> the ``(cell, variant)`` its baselines are set against), the
    figures (``figures``: cell or ``"latency"`` -> path relative to the docs file) and what
    the tables leave out: the ``retired`` cells and ``superseded`` variants (name -> why)."""
    retired, superseded = retired or {}, superseded or {}
    left_out = hidden_text(cells, retired, superseded)
    cells = {
        cell: {v: rs for v, rs in variants.items() if v not in superseded}
        for cell, variants in cells.items()
        if cell not in retired
    }
    cell_order = list(cell_about)
    everything = [r for variants in cells.values() for rs in variants.values() for r in rs]
    hosts = {r["provenance"]["host"] for r in everything if r.get("provenance")}
    unrecorded = sum(not r.get("provenance") for r in everything)
    begin, end = markers(budget)
    parts = [
        begin,
        f"## Learning suite, budget `{budget}`",
        f"_Generated by `{command}` from the JSONs under `{results_dir}`; everything between "
        "the markers is rewritten._",
    ]
    claims = claims_table(cells)
    if claims.count("\n") > 1:
        parts += [
            "### What holds now",
            "Each comparison the results rest on, as a paired difference *a − b* over the "
            "seeds both ran (same data and env seeds): mean ± 95 % t half-width, ▲ / ▼ when "
            "that interval excludes 0 (*ahead* / *behind*), ≈ when it holds 0; *level* when "
            "the equivalence test below also puts it within ±10 points, *not shown* when "
            "neither holds.",
            EQUIVALENCE_ABOUT,
            claims,
        ]
    parts += [
        "### How the runs were made",
        header,
        f"Runs on: {run_on(everything) if everything else '—'}; host ids "
        f"(`benchmarks/provenance/`) recorded for {len(everything) - unrecorded} of "
        f"{len(everything)} runs ({len(hosts)} hosts). The *CPU · commit* column of each "
        "table says where its runs ran; every paired comparison says whether its runs share "
        "one host and commit.",
        "Each entry is the mean over seeds ± the half-width of the 95 % Student-t interval "
        "(n − 1 degrees of freedom). *Offline score*: after the offline phase (0 online "
        "frames); *final*: at the last online evaluation; *AUC*: the trapezoid mean of the "
        "normalized score over online frames, from the offline point to the end; *wall min*: "
        "mean minutes of offline + online phase (a shared offline phase counts in full); "
        "*epistemic share*: the epistemic variance of Eq. 9 as a share of the executed "
        "variance, averaged over the online batches of each run (≤: an upper bound for runs "
        "that logged the epistemic and executed stds but not the share; — without an "
        "ensemble, or for runs that logged neither). *vs dual*: ▲ / ▼ when the variant's "
        "interval lies entirely above / below DUAL's, ≈ when they overlap, ? with fewer than "
        "2 seeds. Non-overlap of two 95 % intervals is a conservative test (about 2.8 "
        "standard errors of the difference for two intervals of equal width), so "
        "overlapping intervals can still differ significantly: the paired tables test that.",
    ]
    if not cells:
        parts.append("No results yet.")
    for cell in sorted(cells, key=lambda c: cell_order.index(c) if c in cell_order else 99):
        parts.append(f"### {cell}: {cell_about[cell]}" if cell in cell_about else f"### {cell}")
        parts.append(cell_table(cells[cell], variant_order))
        if cell in figures:
            parts.append(f"![learning curves, {cell}]({figures[cell]})")
    table = equal_compute_table(cells, cell_order)
    if table.count("\n") > 1:
        parts += [
            "### DUAL vs IQL at equal steps and at equal wall time",
            "*Equal steps* compares the final scores after the same number of online "
            "frames and updates (the `iql` rows); the `iql_equal_time*` variants give IQL "
            "DUAL's CPU time per run (their overrides above). *Equal time* reads the scores "
            "both have reached after the same time: a run's evaluations are placed at "
            "offline_seconds + (frames / final frames) × online_seconds (the online phase "
            "taken as linear in frames), interpolated linearly and held after the run ends; "
            'before its offline phase ends a run has no score ("offline"). Read at T₁ = the '
            "smaller of the two mean total times and T₂ = IQL's. *clock* `cpu`: the runs' "
            "own CPU seconds (one thread each), used when every run of the pair recorded "
            "them, else `wall`. Jobs sharing the cores inflate both, CPU seconds far less "
            "(measured on a 2-core machine: ×1.2-1.4 for a stage under heavy load, against "
            "×2.9 in wall time).",
            table,
        ]
    parts += pairs_sections(cells, cell_order, dual_from, dual_runs)
    if "latency" in figures:
        parts += [
            "### Action latency vs final score",
            f"![latency vs final score]({figures['latency']})",
        ]
    if left_out:
        parts += [
            "### Not in these tables",
            "Their runs stay under the results directory and in the lab notebook "
            "(`benchmarks/notebook.md`), which records how each result was reached.",
            left_out,
        ]
    parts.append(end)
    return "\n\n".join(parts)


def replace_section(text: str, section: str, budget: str) -> str:
    """``text`` with ``budget``'s marker section replaced by ``section`` (which carries
    the markers); inserted after the first ``# `` title line when they are missing."""
    begin, end = markers(budget)
    if begin in text and end in text:
        head, rest = text.split(begin, 1)
        return head + section + rest.split(end, 1)[1]
    lines = text.splitlines(keepends=True)
    at = next((i + 1 for i, line in enumerate(lines) if line.startswith("# ")), 0)
    head, rest = "".join(lines[:at]), "".join(lines[at:]).lstrip("\n")
    return head + ("\n" if at else "") + section + "\n\n" + rest
