"""The learning suite: a grid of recipe runs (cells × variants × seeds) and its report.

    python -m benchmarks.learning --budget default             # the whole grid, resumable
    python -m benchmarks.learning --dry-run                     # print the queue
    python -m benchmarks.learning --cells umaze --variants dual iql --seeds 0 1 --jobs 2
    python -m benchmarks.learning --report-only --latency-json latency.json
    python -m benchmarks.learning --budget smoke --seeds 0 budget.online_frames=200  # extra overrides
    python -m benchmarks.learning --backend ray --ray-address auto --out /shared/suite  # a Ray cluster

Each run is ``python recipes/o2o.py budget=<budget> <cell overrides> <variant overrides>
seed=<k> num_threads=1 offline_cache=<out>/offline_cache output_dir=<out>/<budget>/<cell>/
<variant>/seed<k> <extra overrides>`` in a subprocess; its ``summary.json`` becomes a
compact ``<results>/<budget>/<cell>/<variant>/seed<k>.json`` (committed). A run whose JSON
exists is skipped; a run directory with a checkpoint but no summary is continued with
``resume=true``. Runs that share their offline phase (same env, seed and algorithm, only
online keys differ) are queued so that the first of each group starts before the others.
At the end the section between the ``learning-suite`` markers of ``docs/results.md`` and
its PNGs under ``docs/figures/`` are regenerated (``report.py``, ``plots.py``). Exit code 1 if any run failed. ``--backend`` picks where the runs
execute: this machine (``local``, ``--jobs`` at a time) or a Ray cluster (``ray``, one
task per run; ``backends.py``, ``docs/scale-out.md``).
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
from contextlib import closing
from datetime import datetime, timezone
from pathlib import Path

from tqdm.auto import tqdm

from benchmarks.learning.backends import BACKENDS, Outcome, add_arguments, check_arguments
from benchmarks.learning.cells import (
    CELLS,
    Cell,
    Run,
    active_cells,
    baseline_duals,
    cell_of,
    dual_cells,
    paper_cells,
)
from benchmarks.learning.cost import queue_cost_text
from benchmarks.learning.paper_tables import gpu_projection_text
from benchmarks.learning.paper_tables import write_report as write_paper_report
from benchmarks.learning.plots import latency_points, plot_cell_curves, plot_latency_vs_score
from benchmarks.learning.report import compact_result, load_results, render_section, replace_section
from benchmarks.learning.variants import RECIPE_SCRIPT, REFERENCE_SCRIPTS, SUPERSEDED, VARIANTS

REPO = Path(__file__).resolve().parents[2]


def build_queue(cells: list[str], variants: list[str] | None, seeds: list[int] | None):
    """The grid's runs (leaders of each offline-sharing group first) and skip notes."""
    from torchrl_dual.recipe import ALGORITHMS

    runs, notes = [], []
    for cell_name in cells:
        cell = cell_of(cell_name)
        for variant in cell.variants:
            if variants is not None and variant not in variants:
                continue
            algo = VARIANTS[variant][0].split("=", 1)[1]
            if algo not in ALGORITHMS:
                notes.append(f"skipped {cell_name}/{variant}: algo={algo} is not in ALGORITHMS")
                continue
            for seed in cell.seed_range(variant):
                if seeds is None or seed in seeds:
                    runs.append(Run(cell_name, variant, seed, cell.overrides + VARIANTS[variant]))
    return order_for_sharing(runs), notes


def order_for_sharing(runs: list[Run]) -> list[Run]:
    """The first run of each offline-sharing group, then the others (stable order), so
    that no run waits on the offline-cache lock while its group's first has not started."""
    seen: set[tuple] = set()
    leaders, followers = [], []
    for run in runs:
        (followers if run.sharing_key() in seen else leaders).append(run)
        seen.add(run.sharing_key())
    return leaders + followers


class Suite:
    """Runs the queue and writes one compact JSON per finished run."""

    def __init__(self, args: argparse.Namespace, extra: list[str]) -> None:
        self.args, self.extra = args, extra

    @staticmethod
    def run_meta(outcome: Outcome) -> dict:
        """What a run's JSON records of where it ran: the node's provenance (host id, CPU,
        commit, dirty flag, date; :mod:`benchmarks.provenance`, read on the node when the
        run started), its commit again as ``commit`` (what older JSONs kept) and the
        node's ``machine`` line (platform, CPUs, torch / torchrl versions)."""
        record = outcome.get("provenance") or {}
        date = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
        return {
            "commit": record.get("commit", "?"),
            "machine": outcome["machine"],
            "date": date,
            "provenance": record,
        }

    def run_dir(self, run: Run) -> Path:
        return self.args.out / self.args.budget / run.cell / run.variant / f"seed{run.seed}"

    def result_path(self, run: Run) -> Path:
        return (
            self.args.results / self.args.budget / run.cell / run.variant / f"seed{run.seed}.json"
        )

    def command(self, run: Run) -> list[str]:
        run_dir = self.run_dir(run)
        resume = (run_dir / "checkpoint.pt").exists()
        return [
            sys.executable,
            *REFERENCE_SCRIPTS.get(run.variant, RECIPE_SCRIPT),
            f"budget={self.args.budget}",
            *run.overrides,
            f"seed={run.seed}",
            "num_threads=1",
            "progress=false",
            f"offline_cache={self.args.out / 'offline_cache'}",
            f"output_dir={run_dir}",
            *(["resume=true"] if resume else []),
            *self.extra,
        ]

    def record(self, run: Run, outcome: Outcome) -> dict:
        """Writes the compact JSON of a finished run from its ``summary.json``."""
        summary = json.loads((self.run_dir(run) / "summary.json").read_text())
        overrides = [*run.overrides, *self.extra]
        meta = self.run_meta(outcome)
        result = compact_result(
            summary, variant=run.variant, cell=run.cell, overrides=overrides, meta=meta
        )
        path = self.result_path(run)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(result, indent=1) + "\n")
        return result

    def run_all(self, runs: list[Run]) -> list[str]:
        """Runs the queue on ``--backend``, writing each run's JSON as it finishes;
        returns the failed runs' names."""
        failed = []
        bar = tqdm(total=len(runs), desc="learning suite", unit="run")
        try:
            with closing(BACKENDS[self.args.backend](self, runs)) as finished:
                for run, outcome in finished:
                    if outcome["error"]:
                        failed.append(run.name())
                        tqdm.write(f"FAILED {run.name()}: {outcome['error']}")
                    else:
                        result = self.record(run, outcome)
                        tqdm.write(
                            f"{run.cell} {run.variant} seed{run.seed}: final score "
                            f"{result['final_score']:.1f}, {outcome['seconds'] / 60:.1f} min"
                        )
                    bar.update()
        except KeyboardInterrupt:  # the backend passed Ctrl-C on: the recipes checkpoint
            tqdm.write("interrupted: start the suite again to continue (resume=true)")
            raise SystemExit(130) from None
        finally:
            bar.close()
        return failed


def queue_status(suite: Suite, runs: list[Run], jobs: int) -> tuple[list[Run], str]:
    """The runs of ``runs`` without a result yet, and a line of how many and their cost."""
    todo = [run for run in runs if not suite.result_path(run).exists()]
    leaders = {run.sharing_key(): run for run in reversed(todo)}  # each key's first
    shares = [leaders[run.sharing_key()] is not run for run in todo]
    results = load_results(suite.args.results / suite.args.budget)
    return todo, (
        f"{len(runs)} runs in the grid, {len(runs) - len(todo)} already done, "
        f"{len(todo)} to run\n{queue_cost_text(todo, results, jobs, shares)}"
    )


def cost_text(args: argparse.Namespace, cells: dict[str, dict[str, list[dict]]]) -> str:
    """The report's cost paragraph: what the finished runs took, what the grid has left."""
    done = [r for variants in cells.values() for rs in variants.values() for r in rs]
    cpu = sum(r.get("cpu_seconds") or r.get("wall_seconds") or 0.0 for r in done) / 3600
    wall = sum(r.get("wall_seconds") or 0.0 for r in done) / 3600
    runs, _ = build_queue(active_cells(), None, None)
    _, status = queue_status(Suite(args, []), runs, jobs=os.cpu_count() or 1)
    return (
        f"**Cost.** The {len(done)} runs here took {cpu:.1f} CPU-hours ({wall:.1f} hours of "
        "wall time summed over runs, which shared the cores; runs from before CPU seconds "
        f"were recorded count their wall time). The whole grid: {status.replace(chr(10), '; ')}."
    )


def report(args: argparse.Namespace, command: str) -> None:
    """Regenerates the marker section of ``--docs`` and its PNGs from ``--results``."""
    order = list(VARIANTS)
    cells = {
        cell: dict(
            sorted(variants.items(), key=lambda kv: order.index(kv[0]) if kv[0] in order else 99)
        )
        for cell, variants in load_results(args.results / args.budget).items()
    }
    figures: dict[str, str] = {}
    for cell, variants in cells.items():
        if cell in CELLS and CELLS[cell].retired:
            continue  # left out of the tables: no figure
        png = args.figures / f"learning_{args.budget}_{cell}.png"
        plot_cell_curves(variants, png, title=f"{cell}, budget {args.budget}")
        figures[cell] = os.path.relpath(png, args.docs.parent)
    if args.latency_json and "umaze" in cells:
        points = latency_points(cells["umaze"], json.loads(args.latency_json.read_text()))
        if points:
            png = args.figures / f"latency_vs_score_{args.budget}.png"
            plot_latency_vs_score(points, png, title=f"U-maze, budget {args.budget}")
            figures["latency"] = os.path.relpath(png, args.docs.parent)
    section = render_section(
        cells,
        budget=args.budget,
        header=header_text(args.budget) + "\n\n" + cost_text(args, cells),
        cell_about={name: cell.about for name, cell in {**CELLS, **paper_cells()}.items()},
        dual_from=dual_cells(),
        dual_runs=baseline_duals(),
        variant_order=list(VARIANTS),
        figures=figures,
        command=command,
        results_dir=os.path.relpath(args.results / args.budget, Path.cwd()),
        retired={name: cell.retired for name, cell in CELLS.items() if cell.retired},
        superseded=SUPERSEDED,
    )
    text = args.docs.read_text() if args.docs.exists() else "# Learning results\n"
    args.docs.write_text(replace_section(text, section, args.budget))
    print(f"report: {args.docs} ({len(figures)} figures under {args.figures})")
    if (args.budget == "paper" or set(cells) & set(paper_cells())) and args.paper_docs.exists():
        write_paper_report(cells, args.paper_docs)


def seeds_text(cell: Cell) -> str:
    """The seeds column: the cell's count, and the variants that run more.

    Examples:
        >>> seeds_text(Cell((), ("a", "b"), 5, "", more_seeds=(("b", 7),)))
        '5 (`b`: 7)'
    """
    more = ", ".join(f"`{variant}`: {n}" for variant, n in cell.more_seeds)
    count = f"{cell.seeds} ({more})" if more else str(cell.seeds)
    if cell.first_seed:
        count += f", seeds {cell.first_seed}-{cell.first_seed + cell.seeds - 1}"
    return count


def header_text(budget: str) -> str:
    active = {name: cell for name, cell in CELLS.items() if not cell.retired}
    rows = "\n".join(
        f"| {name} | {cell.about} | `{' '.join(cell.overrides)}` | "
        f"{', '.join(f'`{v}`' for v in cell.variants if v not in SUPERSEDED)} | "
        f"{seeds_text(cell)} |"
        for name, cell in active.items()
    )
    variants = "; ".join(
        f"`{v}` = `{' '.join(o)}`" for v, o in VARIANTS.items() if v not in SUPERSEDED
    )
    return (
        "`python -m benchmarks.learning` runs every cell × variant × seed below as one recipe "
        f"run (`python recipes/o2o.py budget={budget} <cell> <variant> seed=<k> "
        "num_threads=1`), one process per core, resumable, and regenerates this section:\n\n"
        "```bash\npython -m benchmarks.learning --budget default            # the grid\n"
        "python -m benchmarks.learning --budget default --report-only \\\n"
        "    --latency-json latency.json   "
        "# from: python -m benchmarks.speed.latency --json latency.json\n```\n\n"
        "| cell | what | overrides | variants | seeds |\n|---|---|---|---|---|\n"
        f"{rows}\n\nVariants: {variants}. A variant whose `algo` is not in "
        "`torchrl_dual.recipe.ALGORITHMS` is skipped with a note. Runs that differ only in "
        "online keys (the shifts, `laplace.num_samples`, `exploration.shift_weight`, "
        "`online.offline_fraction`, `online.utd_ratio`, ...: "
        "`benchmarks.learning.variants.ONLINE_ONLY`) share one offline phase "
        "(`offline_cache=`), trained once per env and seed. The measured "
        "wall and CPU minutes of each run are in the tables."
    )


def split_argv(argv: list[str]) -> tuple[list[str], list[str]]:
    """(script flags, ``key=value`` recipe overrides)."""
    extra = [a for a in argv if "=" in a and not a.startswith("-")]
    return [a for a in argv if a not in extra], extra


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    flags, extra = split_argv(argv)
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks.learning", description=__doc__.split("\n")[0]
    )
    parser.add_argument("--budget", default="default")
    parser.add_argument(
        "--cells",
        nargs="+",
        choices=[*CELLS, *paper_cells()],
        default=active_cells(),
        help="default: every cell but the retired ones and the paper's (t1_*, t2_*, t3_*)",
    )
    parser.add_argument("--variants", nargs="+", choices=list(VARIANTS))
    parser.add_argument("--seeds", nargs="+", type=int)
    add_arguments(parser)  # --backend, --jobs, --ray-address, --ray-retries
    parser.add_argument(
        "--out",
        type=Path,
        default=REPO / "outputs" / "suite",
        help="run dirs (ray: shared storage)",
    )
    parser.add_argument("--results", type=Path, default=REPO / "benchmarks" / "results")
    parser.add_argument("--docs", type=Path, default=REPO / "docs" / "results.md")
    parser.add_argument("--figures", type=Path, default=REPO / "docs" / "figures")
    parser.add_argument(
        "--paper-docs",
        type=Path,
        default=REPO / "docs" / "reproducing.md",
        help="where the paper's tables are set next to ours (cells t1_*, t2_*, t3_*)",
    )
    parser.add_argument(
        "--latency-json", type=Path, help="from python -m benchmarks.speed.latency --json"
    )
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument("--dry-run", action="store_true", help="print the queue and stop")
    args = parser.parse_args(flags)
    check_arguments(parser, args)
    for name in ("out", "results", "docs", "figures", "paper_docs"):
        setattr(args, name, (Path.cwd() / getattr(args, name)).resolve())
    command = "python -m benchmarks.learning " + shlex.join(argv)
    failed: list[str] = []
    if not args.report_only:
        suite = Suite(args, extra)
        runs, notes = build_queue(args.cells, args.variants, args.seeds)
        for note in notes:
            print(note)
        todo, status = queue_status(suite, runs, args.jobs)
        print(status)
        if any(run.cell in paper_cells() for run in todo):
            print(gpu_projection_text(sum(run.cell in paper_cells() for run in todo)))
        if args.dry_run:
            for run in todo:
                print(shlex.join(suite.command(run)[1:]))
            return 0
        failed = suite.run_all(todo)
    report(args, command.strip())
    if failed:
        print(f"{len(failed)} runs failed: {', '.join(sorted(failed))}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
