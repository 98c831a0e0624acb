"""DUAL against IQL at equal steps and at equal time, for the learning suite's report
(``report.py``): a run's score at a given CPU or wall-clock second, and the table of
DUAL's and each IQL variant's scores at the same time.

    >>> run = {"offline_seconds": 10.0, "wall_seconds": 30.0,
    ...        "history": [{"frames": 0, "normalized_score": 0.0},
    ...                    {"frames": 100, "normalized_score": 50.0}]}
    >>> score_at_time(run, 5.0), score_at_time(run, 20.0)
    (None, 25.0)
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable, Sequence

from benchmarks.learning.pairs import same_host_and_commit
from benchmarks.learning.stats import fmt, t_interval
from benchmarks.learning.variants import IQL_VARIANTS


def clock_of(results: Iterable[dict]) -> str:
    """``"cpu"`` when every result has CPU seconds (summaries written since they are
    recorded), else ``"wall"``: one clock for a whole comparison."""
    return "cpu" if all(r.get("cpu_seconds") is not None for r in results) else "wall"


def run_seconds(result: dict, clock: str = "wall") -> tuple[float, float]:
    """``(offline, total)`` seconds of one run on ``clock`` (``"wall"`` or ``"cpu"``).

    CPU seconds are the run process's (``num_threads=1`` in the suite: the time the run
    would take alone on an idle core); wall seconds grow when other jobs share the cores.
    """
    if clock == "cpu":
        return result["offline_cpu_seconds"], result["cpu_seconds"]
    return result["offline_seconds"], result["wall_seconds"]


def eval_times(result: dict, clock: str = "wall") -> list[float]:
    """Second of each history point on ``clock``: offline seconds + (frames / last
    frame) x online seconds (the online phase taken as linear in frames)."""
    last = max(float(result["history"][-1]["frames"]), 1.0)
    offline, total = run_seconds(result, clock)
    return [offline + h["frames"] / last * (total - offline) for h in result["history"]]


def score_at_time(result: dict, seconds: float, clock: str = "wall") -> float | None:
    """Normalized score at ``seconds`` on ``clock``, linear between evaluations;
    ``None`` while the offline phase is still running, the final score after the end."""
    times = eval_times(result, clock)
    scores = [h["normalized_score"] for h in result["history"]]
    if seconds < times[0]:
        return None
    for i in range(len(times) - 1):
        if seconds <= times[i + 1]:
            span = times[i + 1] - times[i]
            w = (seconds - times[i]) / span if span > 0 else 1.0
            return scores[i] + w * (scores[i + 1] - scores[i])
    return scores[-1]


def _at_time(results: list[dict], seconds: float, clock: str) -> str:
    scores = [score_at_time(r, seconds, clock) for r in results]
    done = [s for s in scores if s is not None]
    if not done:
        return "offline"
    text = fmt(t_interval(done))
    return text if len(done) == len(scores) else f"{text} ({len(scores) - len(done)} offline)"


def equal_compute_table(
    cells: dict[str, dict[str, list[dict]]],
    order: Sequence[str],
    iql_variants: Sequence[str] = IQL_VARIANTS,
) -> str:
    """DUAL vs each IQL variant of a cell: final scores (equal steps for ``iql``) and the
    scores at equal time, on CPU seconds when every run of the pair has them
    (:func:`clock_of`), else wall."""
    lines = [
        "| cell | IQL variant | final dual | final iql | clock | T₁ (min) | dual at T₁ "
        "| iql at T₁ | T₂ (min) | dual at T₂ | iql at T₂ | one host, one commit? |",
        "|---|---|---|---|---|---:|---|---|---:|---|---|---|",
    ]
    for cell in sorted(cells, key=lambda c: order.index(c) if c in order else len(order)):
        dual = cells[cell].get("dual")
        for name in iql_variants:
            iql = cells[cell].get(name)
            if not dual or not iql:
                continue
            clock = clock_of([*dual, *iql])
            total = {
                k: statistics.fmean(run_seconds(r, clock)[1] for r in rs)
                for k, rs in (("d", dual), ("i", iql))
            }
            t1, t2 = min(total.values()), total["i"]
            lines.append(
                f"| {cell} | `{name}` | {fmt(t_interval([r['final_score'] for r in dual]))} "
                f"| {fmt(t_interval([r['final_score'] for r in iql]))} | {clock} "
                f"| {t1 / 60:.1f} | {_at_time(dual, t1, clock)} | {_at_time(iql, t1, clock)} "
                f"| {t2 / 60:.1f} | {_at_time(dual, t2, clock)} | {_at_time(iql, t2, clock)} "
                f"| {same_host_and_commit(dual, iql)} |"
            )
    return "\n".join(lines)
