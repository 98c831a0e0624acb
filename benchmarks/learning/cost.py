"""What the learning suite's queue will cost, from the runs it already finished.

Each queued run is priced at the median CPU seconds (``cpu_seconds``; ``wall_seconds``
for JSONs from before it) of the finished runs of the same variant in the same cell, else
of the same variant on the same env in another cell (a shift changes little of the cost),
else of any variant with the same ``algo=`` and ``critic=`` on the same env (an ablation
switch or a shift changes little of it either).
A run that shares its offline phase with an earlier run of the queue loads it from the
cache: it is priced without the offline CPU seconds of its likes (``offline_cpu_seconds``).
One whose phase a finished run left in the cache is still priced in full (an upper
estimate for it).
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


def _seconds(result: dict, online_only: bool) -> float | None:
    value = result.get("cpu_seconds", result.get("wall_seconds"))
    if value is None:
        return None
    offline = result.get("offline_cpu_seconds") if online_only else None
    return float(value) - float(offline or 0.0)


def run_cost(
    run: QueuedRun, results: dict[str, dict[str, list[dict]]], *, shares_offline: bool = False
) -> float | None:
    """The median measured seconds of ``run``'s likes (see the module docstring), without
    their offline phase if ``shares_offline``; None if nothing like it has finished."""
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
        seconds = [s for r in pool if (s := _seconds(r, shares_offline)) is not None]
        if seconds:
            return statistics.median(seconds)
    return None


def queue_cost_text(
    todo: Sequence[QueuedRun],
    results: dict[str, dict[str, list[dict]]],
    jobs: int,
    shares_offline: Sequence[bool] | None = None,
) -> str:
    """One paragraph: the queue's estimated CPU hours, the hours on ``jobs`` parallel
    runs, and the runs nothing measured yet prices. ``shares_offline[i]``: run ``i``
    loads its offline phase from an earlier run of the queue.

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
    shared = shares_offline or [False] * len(todo)
    costs = [
        (run, run_cost(run, results, shares_offline=sh))
        for run, sh in zip(todo, shared, strict=True)
    ]
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
