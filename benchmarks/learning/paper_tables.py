"""The paper's Tables 1-3 as data, the learning-suite cells that rerun them, and the report
that puts our numbers next to the paper's.

    python -m benchmarks.learning --budget paper --cells $(python -m benchmarks.learning.paper_tables --cells 1) --dry-run
    python -m benchmarks.learning --budget paper --backend ray --gpus-per-run 1 \\
        --cells $(python -m benchmarks.learning.paper_tables --cells 1) device=cuda
    python -m benchmarks.learning --budget paper --report-only   # docs/reproducing.md's tables

Each row of a table is one cell ``t<table>_<row>`` (e.g. ``t1_antmaze_umaze``) with the
recipe overrides of the row's Minari data set and one variant per column we can run; the
paper's mean ± standard deviation over its 5 seeds is stored for every (table, row, column)
(:data:`PAPER`, copied from the paper's LaTeX source). Rows whose D4RL data set has no
Minari counterpart (``medium-replay``, ``medium-expert``) and columns whose method does not
run on that critic here (EDIS, Diff-QL, DACER on Cal-QL or SO2) are listed with the reason
and queue no run. The report (between the ``paper-tables`` markers of
``docs/reproducing.md``, written by the suite's report) shows ``ours (mean ± sd, 95 % t half-width, n)``
next to the paper's for every cell of ``benchmarks/results/<budget>/``.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path

from benchmarks.learning.stats import t_interval

REPO = Path(__file__).resolve().parents[2]
BEGIN, END = "<!-- paper-tables:begin -->", "<!-- paper-tables:end -->"

COLUMNS: dict[int, tuple[tuple[str, str | None], ...]] = {
    1: (
        ("IQL", "iql"),
        ("EDIS", "edis"),
        ("Diffuser", "diffuser"),
        ("Diff-QL", "diffql"),
        ("DACER", "dacer"),
        ("DUAL", "dual"),
    ),
    2: (
        ("Cal-QL: Base", "calql"),
        ("Cal-QL: EDIS", None),
        ("Cal-QL: Diff-QL", None),
        ("Cal-QL: DUAL", "dual_calql"),
        ("SO2+OFF2ON: Base", "so2"),
        ("SO2+OFF2ON: Diff-QL", None),
        ("SO2+OFF2ON: DACER", None),
        ("SO2+OFF2ON: DUAL", "dual_so2"),
    ),
    3: (
        ("IQL: Base", "iql"),
        ("IQL: EDIS", "edis"),
        ("IQL: Diff-QL", "diffql"),
        ("IQL: DUAL", "dual"),
        ("Cal-QL: Base", "calql"),
        ("Cal-QL: EDIS", None),
        ("Cal-QL: Diff-QL", None),
        ("Cal-QL: DUAL", "dual_calql"),
    ),
}
"""Table -> its columns: (the paper's header, our variant or ``None`` where the method
does not run on that critic here: EDIS, Diff-QL and DACER support ``critic=iql`` only)."""

# The paper's numbers: "row | mean sd | mean sd | ..." in the table's column order.
_TABLE_1 = """
halfcheetah-medium-v2 | 48.35 1.19 | 49.34 1.39 | 48.20 0.92 | 48.61 1.37 | 49.92 0.89 | 49.83 1.09
halfcheetah-medium-replay-v2 | 45.77 1.24 | 46.65 1.38 | 45.82 1.87 | 46.91 1.70 | 48.18 1.00 | 48.78 1.30
halfcheetah-medium-expert-v2 | 95.77 1.52 | 98.24 1.91 | 96.60 1.91 | 99.88 1.79 | 102.18 1.37 | 103.11 1.75
hopper-medium-v2 | 66.61 2.68 | 68.90 2.71 | 70.43 2.27 | 80.26 2.69 | 83.05 2.29 | 88.23 3.42
hopper-medium-replay-v2 | 101.01 2.13 | 103.55 2.46 | 96.57 3.55 | 108.27 2.42 | 110.06 2.01 | 109.21 2.41
hopper-medium-expert-v2 | 107.48 3.29 | 109.93 3.41 | 106.73 3.33 | 110.94 4.16 | 113.88 3.57 | 115.33 4.58
walker2d-medium-v2 | 84.20 1.61 | 86.11 1.81 | 83.57 1.77 | 86.14 1.74 | 90.05 1.39 | 89.15 1.64
walker2d-medium-replay-v2 | 84.04 1.67 | 89.53 1.85 | 85.51 2.13 | 87.88 1.80 | 90.83 1.44 | 93.15 1.86
walker2d-medium-expert-v2 | 111.52 1.28 | 111.02 1.31 | 111.87 0.83 | 112.48 0.92 | 112.43 0.96 | 112.62 1.18
antmaze-umaze-v2 | 90.38 2.24 | 90.10 1.20 | 89.75 1.24 | 90.91 1.45 | 91.31 1.82 | 94.69 4.00
antmaze-umaze-diverse-v2 | 35.95 15.16 | 35.82 11.62 | 35.71 10.36 | 49.37 10.78 | 51.73 7.94 | 78.06 9.03
antmaze-medium-play-v2 | 85.03 2.63 | 84.15 2.00 | 86.45 1.70 | 87.44 1.77 | 87.46 1.18 | 92.29 2.40
antmaze-medium-diverse-v2 | 84.10 2.25 | 83.55 2.80 | 86.58 1.84 | 86.75 1.52 | 86.93 1.68 | 91.86 2.76
antmaze-large-play-v2 | 54.16 4.00 | 56.80 3.70 | 59.21 2.32 | 58.40 3.65 | 60.50 3.25 | 70.27 4.72
antmaze-large-diverse-v2 | 50.21 3.83 | 53.57 5.02 | 55.64 3.05 | 51.13 3.55 | 52.30 4.47 | 64.21 4.63
"""
_TABLE_2 = """
halfcheetah-medium-v2 | 74.14 1.39 | 80.18 1.55 | 80.37 1.28 | 84.61 1.86 | 77.72 1.01 | 79.48 1.43 | 80.00 0.77 | 81.78 1.11
halfcheetah-medium-replay-v2 | 75.20 0.95 | 82.16 1.28 | 84.74 1.21 | 86.99 2.00 | 68.70 0.85 | 70.18 1.25 | 72.50 0.77 | 74.42 1.20
hopper-medium-v2 | 98.21 1.93 | 104.51 2.30 | 102.04 1.33 | 107.95 1.77 | 88.84 2.33 | 94.30 1.73 | 96.97 1.53 | 100.78 1.59
walker2d-medium-v2 | 98.77 1.81 | 103.54 2.06 | 106.80 1.53 | 109.10 1.93 | 88.87 0.53 | 91.02 1.37 | 92.38 0.46 | 94.45 0.58
halfcheetah-friction-2.0 | 61.20 1.19 | 62.65 0.51 | 62.68 1.31 | 67.16 1.02 | 56.60 0.90 | 57.35 1.25 | 60.21 1.29 | 61.94 0.62
halfcheetah-med-gravity-2.0 | 44.98 1.08 | 46.19 0.65 | 47.48 1.63 | 53.41 1.10 | 42.52 2.61 | 45.02 2.66 | 47.93 2.72 | 49.97 1.49
hopper-kinematic-2.0 | 55.46 3.01 | 58.01 2.44 | 62.93 2.09 | 68.70 1.86 | 51.63 5.95 | 59.15 3.43 | 61.55 3.64 | 63.00 2.20
walker2d-morphology-2.0 | 52.70 1.70 | 55.17 0.59 | 56.93 2.37 | 61.22 0.92 | 48.96 4.01 | 53.01 4.03 | 56.23 4.25 | 58.63 2.51
"""
_TABLE_3 = """
pen-cloned-v1 | 94.74 12.12 | 97.31 12.73 | 104.45 12.14 | 124.40 19.09 | -2.69 0.14 | -2.23 0.30 | -1.93 0.47 | -1.09 0.35
door-cloned-v1 | 9.79 4.98 | 10.46 5.10 | 11.55 4.93 | 15.26 4.86 | -0.33 0.01 | -0.32 0.01 | -0.31 0.01 | -0.28 0.01
hammer-cloned-v1 | 27.41 13.36 | 28.00 13.42 | 33.82 12.10 | 46.74 9.85 | 0.26 0.28 | 0.35 0.31 | 0.32 0.21 | 0.68 0.23
relocate-cloned-v1 | 0.10 0.05 | 0.14 0.06 | 0.23 0.05 | 0.44 0.06 | -0.28 0.08 | -0.24 0.08 | -0.26 0.02 | -0.12 0.08
"""


def _parse(table: int, text: str) -> dict[tuple[int, str, str], tuple[float, float]]:
    out = {}
    for line in text.strip().splitlines():
        row, *cells = (part.strip() for part in line.split("|"))
        headers = [header for header, _ in COLUMNS[table]]
        if len(cells) != len(headers):
            raise ValueError(
                f"table {table}, {row}: {len(cells)} numbers for {len(headers)} columns"
            )
        for header, cell in zip(headers, cells, strict=True):
            mean, sd = (float(v) for v in cell.split())
            out[(table, row, header)] = (mean, sd)
    return out


PAPER: dict[tuple[int, str, str], tuple[float, float]] = {
    **_parse(1, _TABLE_1),
    **_parse(2, _TABLE_2),
    **_parse(3, _TABLE_3),
}
"""(table, row, column header) -> the paper's (mean, sd) over 5 seeds of the normalized
score after 1M offline and 1M online steps."""

_ODRL = {  # ODRL rows: (robot, D4RL data set, shift); all at shift level 2.0 (appendix)
    "halfcheetah-friction-2.0": ("halfcheetah", "medium", "friction"),
    "halfcheetah-med-gravity-2.0": ("halfcheetah", "medium-replay", "gravity"),
    "hopper-kinematic-2.0": ("hopper", "medium", "kinematic"),
    "walker2d-morphology-2.0": ("walker2d", "medium", "morphology"),
}
MINARI_LOCOMOTION = ("medium", "expert", "simple")
"""Minari's ``mujoco/<robot>/<name>-v0`` data sets (no ``medium-replay``/``medium-expert``)."""
ANTMAZE_MINARI_DATA = {
    "umaze": "umaze",
    "umaze-diverse": "umaze-diverse",
    "medium-play": "medium-diverse",
    "medium-diverse": "medium-play",
    "large-play": "large-diverse",
    "large-diverse": "large-play",
}
"""D4RL's AntMaze data set -> the Minari one (``D4RL/antmaze/<name>-v1``) with its layout.
D4RL's ``play`` sets command the ant to a few hand-picked goals, its ``diverse`` sets to
goals anywhere. Minari's generation script (``scripts/antmaze/create_antmaze_dataset.py``,
``DATASET_ID_TO_ENV_ID``) recorded its ``medium-play``/``large-play`` in
``AntMaze_Medium-v4``/``AntMaze_Large-v4`` (goals and resets in any free cell) and its
``medium-diverse``/``large-diverse`` in ``AntMaze_*_Diverse_GR-v4`` (the hand-picked ``c``
cells): the names are swapped, so D4RL's play row reads Minari's diverse set and the
other way round. ``umaze`` (one goal) and ``umaze-diverse`` (goals anywhere in the
registered ``U_MAZE``) keep their names."""


@dataclass(frozen=True)
class PaperRow:
    """One row of a table and how it runs here.

    Args:
        table (int): 1, 2 or 3.
        row (str): the paper's row label, e.g. ``antmaze-umaze-v2``.
        overrides (tuple of str): the recipe overrides of its data set and shift.
        unavailable (str): why it cannot run here (empty: it can).
        data (str): the Minari data set it reads (empty when it cannot run).
    """

    table: int
    row: str
    overrides: tuple[str, ...]
    unavailable: str = ""
    data: str = ""

    @property
    def label(self) -> str:
        """The row as the report names it: the paper's label and the Minari data set it
        reads, or why it cannot run.

        Examples:
            >>> next(r for r in ROWS if r.row == "antmaze-large-play-v2").label
            "`antmaze-large-play-v2` (data: `D4RL/antmaze/large-diverse-v1`, D4RL's play layout under Minari's other name)"
        """
        if self.unavailable:
            return f"`{self.row}` ({self.unavailable})"
        name = self.data.split("/")[-1].rsplit("-v", 1)[0]
        d4rl = self.row.removeprefix("antmaze-").rsplit("-v", 1)[0]
        swapped = self.row.startswith("antmaze-") and name != d4rl
        why = f", D4RL's {d4rl.split('-')[1]} layout under Minari's other name" if swapped else ""
        return f"`{self.row}` (data: `{self.data}`{why})"

    @property
    def cell(self) -> str:
        """Its learning-suite cell, e.g. ``t1_antmaze_umaze``."""
        name = self.row.removesuffix("-v2").removesuffix("-v1").replace("-2.0", "")
        return f"t{self.table}_" + name.replace("-", "_")

    @property
    def variants(self) -> tuple[str, ...]:
        return tuple(v for _, v in COLUMNS[self.table] if v is not None)


def _row(table: int, row: str) -> PaperRow:
    name = row.removesuffix("-v2").removesuffix("-v1")
    if row in _ODRL:
        robot, dataset, shift = _ODRL[row]
        extra = (f"env.shift={shift}", "env.shift_scale=2.0")
    elif name.startswith("antmaze-"):
        dataset = ANTMAZE_MINARI_DATA[name.removeprefix("antmaze-")]
        overrides = ("env=antmaze", f"env.dataset={dataset}")
        return PaperRow(table, row, overrides, data=f"D4RL/antmaze/{dataset}-v1")
    elif name.split("-")[0] in ("pen", "door", "hammer", "relocate"):
        task, dataset = name.split("-", 1)
        overrides = ("env=adroit", f"env.task={task}", f"env.dataset={dataset}")
        return PaperRow(table, row, overrides, data=f"D4RL/{task}/{dataset}-v2")
    else:
        robot, dataset = name.split("-", 1)
        extra = ()
    overrides = (f"env={robot}", f"env.dataset={dataset}", *extra)
    if dataset not in MINARI_LOCOMOTION:
        return PaperRow(
            table, row, overrides,
            f"Minari has no mujoco/{robot}/{dataset} data set",
        )  # fmt: skip
    return PaperRow(table, row, overrides, data=f"mujoco/{robot}/{dataset}-v0")


ROWS: tuple[PaperRow, ...] = tuple(
    _row(table, row) for table, row in dict.fromkeys((t, r) for t, r, _ in PAPER)
)
"""Every row of the three tables, in the paper's order."""


def runnable_rows(table: int | None = None) -> list[PaperRow]:
    """The rows that run here (of one table, or of all).

    Examples:
        >>> [r.cell for r in runnable_rows(3)][:2]
        ['t3_pen_cloned', 't3_door_cloned']
        >>> len(runnable_rows(1)), len(ROWS)
        (9, 27)
    """
    return [r for r in ROWS if not r.unavailable and (table is None or r.table == table)]


# ----------------------------------------------------------------------------- cost
GPU_PROJECTION = REPO / "benchmarks/results/gpu_throughput_h200_2026-12-04.json"
"""The measured GPU rates ``budget=paper`` runs are projected from (``gpu_throughput.py``)."""


def gpu_projection_text(runs: int, path: Path = GPU_PROJECTION) -> str:
    """One paragraph: the GPU hours of ``runs`` paper runs, each priced at the projection of
    one DUAL ``budget=paper`` AntMaze run in ``path`` (with where its inputs come from).

    Examples:
        >>> print(gpu_projection_text(2).split(";")[0])
        projected GPU time of the 2 paper runs to go: 2 x 2.33 h = 4.7 GPU-hours
    """
    import json

    from benchmarks.speed.gpu_projection import PAPER, project_paper

    report = json.loads(path.read_text())  # its rates, priced at today's budget=paper
    hours = project_paper(report["results"], report["env_step_ms"], report["eval_hours"])
    return (
        f"projected GPU time of the {runs} paper runs to go: {runs} x {hours['total']:.2f} h = "
        f"{runs * hours['total']:.1f} GPU-hours; each priced as one DUAL budget=paper AntMaze run "
        f"on one {report['device_name']} ({path.relative_to(REPO)}, {report['date']}: its "
        f"update rates measured there, {hours['online_steps']:.2f} h of 1M env steps at "
        f"{report['env_step_ms']} ms measured on a CPU, {report['eval_hours']} h of evaluation "
        f"assumed, not measured; {PAPER['utd_ratio']:g} online update per env step); an upper "
        "bound for the methods without a planner, whose env steps cost the same"
    )


# ----------------------------------------------------------------------------- report
def ours_cell(results: list[dict]) -> str:
    """Our final normalized score over seeds: ``mean ± sd`` (the paper's form, to compare
    with its column) and the 95 % Student-t interval's half-width (the project's form).

    >>> ours_cell([{"final_score": s} for s in (60.0, 70.0, 80.0)])
    '70.0 ± 10.0 (95 % t ± 24.8, n = 3)'
    """
    scores = [r["final_score"] for r in results if math.isfinite(r.get("final_score", math.nan))]
    if not scores:
        return "—"
    if len(scores) == 1:
        return f"{scores[0]:.1f} (n = 1)"
    mean, half = t_interval(scores)
    sd = statistics.stdev(scores)
    return f"{mean:.1f} ± {sd:.1f} (95 % t ± {half:.1f}, n = {len(scores)})"


def render_tables(results: dict[str, dict[str, list[dict]]]) -> str:
    """Markdown: for each table, every row and column, ours next to the paper's.

    ``results``: ``{cell: {variant: [compact run JSON, ...]}}`` of ``budget=paper``.
    """
    parts = []
    for table, columns in COLUMNS.items():
        header = "| row | " + " | ".join(h for h, _ in columns) + " |"
        rule = "|---" * (len(columns) + 1) + "|"
        lines = [
            f"**Table {table}** (ours / paper, normalized score, mean ± sd over seeds; ours "
            "also with the half-width of its 95 % t interval)",
            "",
            header,
            rule,
        ]
        for row in (r for r in ROWS if r.table == table):
            cells = []
            for column, variant in columns:
                mean, sd = PAPER[(table, row.row, column)]
                if row.unavailable or variant is None:
                    ours = "n/a"
                else:
                    ours = ours_cell(results.get(row.cell, {}).get(variant, []))
                cells.append(f"{ours} / {mean:.2f} ± {sd:.2f}")
            lines.append(f"| {row.label} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts)


def replace_section(text: str, section: str) -> str:
    """``text`` with the part between the markers replaced (markers appended if absent)."""
    block = f"{BEGIN}\n{section}\n{END}"
    if BEGIN in text and END in text:
        head, rest = text.split(BEGIN, 1)
        return head + block + rest.split(END, 1)[1]
    return text.rstrip("\n") + "\n\n" + block + "\n"


def write_report(results: dict[str, dict[str, list[dict]]], docs: Path) -> None:
    """Regenerates the tables between the markers of ``docs`` from ``results``
    (``benchmarks.learning.report.load_results`` of ``benchmarks/results/paper``)."""
    docs.write_text(replace_section(docs.read_text(), render_tables(results)))
    runs = sum(len(v) for c in results.values() for v in c.values())
    print(f"paper tables: {docs} ({runs} runs)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cells", type=int, choices=(1, 2, 3), required=True)
    args = parser.parse_args(argv)
    print(" ".join(r.cell for r in runnable_rows(args.cells)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
