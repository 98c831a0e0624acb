"""What the learning suite's queue will cost, from the runs it already finished.

Each queued run is priced at the median CPU seconds (``cpu_seconds``; ``wall_seconds``
for JSONs from before it) of the finished runs of the same variant in the same cell, else
of the same variant on the same env in another cell (a shift changes little of the cost),
else of any variant with the same ``algo=`` and ``critic=`` on the same env (an ablation
switch or a shift changes little of it either).
Runs that share an offline phase with an earlier run of the queue cost less than this
(their offline stages load from the cache), so the total is an upper estimate for them.
"""

from __future__ import annotations

import statistics
from collections import Counter
from collections.abc import Sequence
from typing import Protocol


class QueuedRun(Protocol):
    cell: str
    variant: str
    overrides: tuple[str, ...]


def _value(overrides: Sequence[str], key: str) -> str | None:
    return next((o.split("=", 1)[1] for o in overrides if o.startswith(f"{key}=")), None)


def _seconds(result: dict) -> float | None:
    value = result.get("cpu_seconds", result.get("wall_seconds"))
    return None if value is None else float(value)


def run_cost(run: QueuedRun, results: dict[str, dict[str, list[dict]]]) -> float | None:
    """The median measured seconds of ``run``'s like (see the module docstring), or None."""
    env = _value(run.overrides, "env")
    on_env = [
        (variant, result)
        for variants in results.values()
        for variant, finished in variants.items()
        for result in finished
        if env is not None and result.get("env") == env
    ]
    kind = [_value(run.overrides, key) for key in ("algo", "critic")]
    same_cell = results.get(run.cell, {}).get(run.variant, [])
    same_variant = [result for variant, result in on_env if variant == run.variant]
    same_kind = [
        result
        for _, result in on_env
        if [_value(result.get("overrides", []), key) for key in ("algo", "critic")] == kind
    ]
    for pool in (same_cell, same_variant, same_kind):
        seconds = [s for s in map(_seconds, pool) if s is not None]
        if seconds:
            return statistics.median(seconds)
    return None


def queue_cost_text(
    todo: Sequence[QueuedRun], results: dict[str, dict[str, list[dict]]], jobs: int
) -> str:
    """One paragraph: the queue's estimated CPU hours, the hours on ``jobs`` parallel
    runs, and the runs nothing measured yet prices.

    Examples:
        >>> from types import SimpleNamespace as Run
        >>> umaze = ("env=pointmaze_umaze", "algo=iql")
        >>> done = {"umaze": {"iql": [{"cpu_seconds": 600.0, "env": "pointmaze_umaze",
        ...     "overrides": list(umaze)}]}}
        >>> todo = [Run(cell="umaze", variant="iql", overrides=umaze),
        ...         Run(cell="umaze_mass", variant="iql_big", overrides=(*umaze, "x=2")),
        ...         Run(cell="medium", variant="iql", overrides=("env=pointmaze_medium",))]
        >>> print(queue_cost_text(todo, done, jobs=2))
        cost of the 3 runs to go, from finished runs like them: ≈ 0.3 CPU-hours for 2 of them (≈ 0.2 h at --jobs 2); not measured yet: medium/iql (1)
    """
    if not todo:
        return "nothing to run"
    costs = [(run, run_cost(run, results)) for run in todo]
    priced = [seconds for _, seconds in costs if seconds is not None]
    unpriced = Counter(f"{run.cell}/{run.variant}" for run, seconds in costs if seconds is None)
    hours = sum(priced) / 3600
    text = (
        f"cost of the {len(todo)} runs to go, from finished runs like them: "
        f"≈ {hours:.1f} CPU-hours for {len(priced)} of them "
        f"(≈ {hours / max(jobs, 1):.1f} h at --jobs {jobs})"
    )
    if unpriced:
        text += "; not measured yet: " + ", ".join(f"{k} ({n})" for k, n in unpriced.items())
    return text
