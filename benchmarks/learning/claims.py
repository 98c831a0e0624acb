"""The claims of the learning suite's report: each comparison the results page states, read
from today's runs (``python -m benchmarks.learning --report-only``), so that the page says
what the runs show now and nothing else.

A claim is a paired difference ``a − b`` (final score and AUC) on the seeds both variants
ran (:mod:`benchmarks.learning.pairs`), read as *ahead* / *behind* when its 95 % t interval
excludes 0, *level* when the equivalence test puts it within ±10 points, *not shown*
otherwise.

    >>> run = lambda s, fin: {"seed": s, "final_score": fin, "auc": fin}
    >>> cells = {"u": {"dual": [run(s, 50.0 + s) for s in range(3)],
    ...                "iql": [run(s, 40.0 + 2 * s) for s in range(3)]}}
    >>> print(claims_table(cells, (Claim("u", "DUAL − IQL", "dual", "iql"),)).splitlines()[-1])
    | u | DUAL − IQL | 0-2 (3) | 42.0 ± 5.0 | 51.0 ± 2.5 | +9.0 ± 2.5 ▲ | +9.0 ± 2.5 ▲ | no [+7.3, +10.7] / no [+7.3, +10.7] | ahead | no: host not recorded, commit not recorded |
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from benchmarks.learning.pairs import (
    paired_difference,
    paired_equivalence,
    same_host_and_commit,
)
from benchmarks.learning.stats import fmt, t_interval


@dataclass(frozen=True)
class Claim:
    """``a − b`` in ``cell``: the runs of variant ``a`` (of ``a_cell`` when set) against those
    of ``b`` (of ``b_cell``), paired by seed."""

    cell: str
    text: str
    a: str
    b: str
    a_cell: str | None = None
    b_cell: str | None = None

    def runs(self, cells: dict[str, dict[str, list[dict]]]) -> tuple[list[dict], list[dict]]:
        """The runs of both sides (empty when a side has none yet)."""
        a = cells.get(self.a_cell or self.cell, {}).get(self.a, [])
        b = cells.get(self.b_cell or self.cell, {}).get(self.b, [])
        return a, b


def _set(cell, text, pairs, **where):
    return tuple(Claim(cell, f"{text} {label}".strip(), a, b, **where) for label, a, b in pairs)


_IQL = (("− IQL, same steps", "dual", "iql"),)
_LAMBDA = (("− DUAL at λ = 0", "dual", "dual_lambda0"),)
CLAIMS: tuple[Claim, ...] = (
    *_set("umaze_fresh", "DUAL", _IQL),
    Claim("umaze_fresh", "DUAL − IQL given DUAL's CPU time", "dual", "iql_equal_time_29k"),
    Claim("umaze_fresh", "DUAL − d3rlpy's IQL", "dual", "iql_d3rlpy"),
    Claim("umaze_fresh", "IQL − d3rlpy's IQL (our baseline at full strength?)", "iql", "iql_d3rlpy"),
    *_set("umaze", "DUAL", _IQL),
    Claim("umaze", "DUAL − IQL given DUAL's CPU time", "dual", "iql_equal_time"),
    Claim("umaze", "DUAL − IQL + LA", "dual", "iql_la"),
    Claim("umaze", "DUAL − Diff-QL", "dual", "diffql"),
    Claim("umaze", "DUAL − Diff-QL w LA", "dual", "diffql_la"),
    Claim("umaze", "DUAL − DUAL without UQ", "dual", "dual_no_uq"),
    *_set("umaze", "DUAL", _LAMBDA),
    *_set(
        "umaze_baselines",
        "DUAL −",
        (("Diffuser", "dual", "diffuser"), ("DACER", "dual", "dacer"), ("EDIS", "dual", "edis")),
        a_cell="umaze_ablations",
    ),
    Claim("umaze_baselines", "DUAL on SO2 + OFF2ON − SO2 + OFF2ON", "dual_so2", "so2"),
    Claim("umaze_baselines", "DUAL on Cal-QL − Cal-QL", "dual_calql", "calql"),
    Claim("umaze_baselines", "Cal-QL − d3rlpy's Cal-QL", "calql", "calql_d3rlpy"),
    Claim("umaze_temperature", "DUAL at T = data − DUAL", "dual_tdata", "dual", b_cell="umaze"),
    *_set("umaze_rotation_onehost", "DUAL", _IQL + _LAMBDA),
    *_set("umaze_rotation_fresh", "DUAL", _IQL + _LAMBDA),
    *_set("umaze_rotation", "DUAL", _IQL + _LAMBDA),
    *_set("umaze_damping", "DUAL", _IQL + _LAMBDA),
    *_set("umaze_mass", "DUAL", _IQL + _LAMBDA),
    *_set("medium_goal_onehost", "DUAL", _IQL),
    *_set("medium_goal_long", "DUAL", _IQL),
    Claim("medium_goal_long", "DUAL − IQL given DUAL's CPU time", "dual", "iql_equal_time_online"),
    *_set("medium_goal_long", "DUAL", _LAMBDA),
    Claim(
        "medium_goal_long", "DUAL − the same noise, state-independent", "dual",
        "dual_constant_noise",
    ),
    Claim("medium_explore_v2", "DUAL at T = data − DUAL without UQ", "dual_tdata", "dual_no_uq"),
    Claim("medium_explore_v2", "DUAL − DUAL without UQ", "dual", "dual_no_uq"),
    *_set("frozenlake8x8_slip", "DUAL", _IQL),
)  # fmt: skip
"""The comparisons the results page reads, by task; a claim whose runs do not exist yet is
left out of the table."""


def seeds_text(seeds: Iterable[int]) -> str:
    """Seeds as ranges: ``0-4``, ``0-2, 5``.

    >>> seeds_text([5, 6, 7, 8, 9]), seeds_text([0, 1, 2, 5])
    ('5-9', '0-2, 5')
    """
    runs: list[list[int]] = []
    for seed in sorted(set(seeds)):
        if runs and seed == runs[-1][-1] + 1:
            runs[-1].append(seed)
        else:
            runs.append([seed])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else str(r[0]) for r in runs)


def reading(marker: str, equivalent: bool | None) -> str:
    """What one paired difference shows: ``ahead`` / ``behind`` (its 95 % interval excludes
    0), ``level`` (inside the noise and equivalent within the margin), ``not shown``
    (neither), ``too few seeds``."""
    if marker == "?" or equivalent is None:
        return "too few seeds"
    if marker in "▲▼":
        return "ahead" if marker == "▲" else "behind"
    return "level" if equivalent else "not shown"


def claims_table(cells: dict[str, dict[str, list[dict]]], claims: Sequence[Claim] = CLAIMS) -> str:
    """Markdown rows ``cell | comparison | seeds (n) | b final | a final | a − b: final |
    a − b: AUC | equivalence verdicts | reading | one host, one commit?`` of every claim
    whose two sides ran a common seed."""
    lines = [
        "| cell | comparison (a − b) | seeds (n) | b: final | a: final | a − b: final "
        "| a − b: AUC | equivalent within ±10? final / AUC | reads | one host, one commit? |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for claim in claims:
        a, b = claim.runs(cells)
        seeds = {r["seed"] for r in a} & {r["seed"] for r in b}
        if not seeds:
            continue
        a, b = ([r for r in side if r["seed"] in seeds] for side in (a, b))
        diffs, readings = [], []
        for key in ("final_score", "auc"):
            n, (mean, half), marker = paired_difference(a, b, key)
            verdict = paired_equivalence(a, b, key)
            diffs.append(f"{mean:+.1f} {marker}" if n < 2 else f"{mean:+.1f} ± {half:.1f} {marker}")
            readings.append((reading(marker, verdict.equivalent), verdict.text()))
        final, auc = (r[0] for r in readings)
        reads = final if final == auc else f"final {final}, AUC {auc}"
        finals = (fmt(t_interval([r["final_score"] for r in side])) for side in (b, a))
        lines.append(
            f"| {claim.cell} | {claim.text} | {seeds_text(seeds)} ({len(seeds)}) | "
            + " | ".join([*finals, *diffs, " / ".join(r[1] for r in readings), reads])
            + f" | {same_host_and_commit(a, b)} |"
        )
    return "\n".join(lines)
