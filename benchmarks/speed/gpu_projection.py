"""The ``budget=paper`` wall time projected from ``gpu_throughput.py``'s rates, and the
merge of several of its JSON reports into one.

The projection of one ``budget=paper`` AntMaze run (1M planner updates, 5 × 20k
distillation updates, 1M offline and 0.5M online actor-critic updates, 1M online steps, a
posterior refit every 10k updates over all transitions) takes, for each update and acting
figure, the fastest mode that ran, and adds two CPU-bound terms measured on the CPU
(docs/benchmarks.md, 2026-12-02): the env and collector cost of an online step
(``--env-step-ms``, 3.9 ms: the 5.2 ms online step less its 1.3 ms policy) and the 21
evaluations of 100 episodes (``--eval-hours``, 0.4 h).

No measurement runs here: ``python -m benchmarks.speed.gpu_throughput --merge a.json
b.json --json all.json`` calls :func:`merge` (e.g. each ``cudagraphs`` figure measured in
its own process: a failed capture leaves the CUDA generator unusable for the next one).

Examples:
    >>> rates = {"planner": 100.0, "distillation": 50.0, "actor_critic": 200.0,
    ...          "act_b1": 1000.0, "act_b64": 500.0}
    >>> results = {n: {"eager": {"per_second": r}} for n, r in rates.items()}
    >>> results["laplace"] = {"eager": {"per_second_1k": 10.0}}
    >>> hours = paper_hours(results, env_step_ms=3.9, eval_hours=0.4)
    >>> round(hours["planner"], 3), round(hours["total"], 2)  # 1M updates at 100/s
    (2.778, 9.29)
    >>> del results["laplace"]
    >>> print(paper_hours(results, env_step_ms=3.9, eval_hours=0.4))  # incomplete
    None
"""

from __future__ import annotations

import json

UPDATES = ("planner", "distillation", "actor_critic")
ACTING = {"act_b1": 1, "act_b64": 64}
"""The acting figures and their batch sizes (states per policy call)."""


def best(results: dict, name: str) -> tuple[str | None, float]:
    """The fastest mode that ran: ``(mode, per second)``; ``(None, nan)`` if none did."""
    ran = {m: r["per_second"] for m, r in results[name].items() if "per_second" in r}
    if not ran:
        return None, float("nan")
    mode = max(ran, key=ran.get)
    return mode, ran[mode]


def best_modes(results: dict) -> dict[str, str | None]:
    """The fastest mode of each update and acting figure (``None`` where none ran)."""
    return {name: best(results, name)[0] for name in (*UPDATES, *ACTING)}


def project_paper(results: dict, env_step_ms: float, eval_hours: float) -> dict[str, float]:
    """Hours of one ``budget=paper`` AntMaze run from the measured rates (see the module
    docstring for the terms and the CPU-bound inputs)."""
    hours = {
        "planner": 1_000_000 / best(results, "planner")[1],
        "distillation": 100_000 / best(results, "distillation")[1],
        "actor_critic": 1_000_000 / best(results, "actor_critic")[1],
        # a fit after the offline phase, then every 10k of the 0.5M online updates over
        # 1M..2M transitions: about 1M + 50 x 1.5M = 76M transitions
        "laplace": 76_000 / results["laplace"]["eager"]["per_second_1k"],
        "online_updates": 500_000 / best(results, "actor_critic")[1],
        "online_steps": 1_000_000 * (env_step_ms / 1000 + 1 / best(results, "act_b1")[1]),
    }
    hours = {k: v / 3600 for k, v in hours.items()}
    hours["evaluation"] = eval_hours
    hours["total"] = sum(hours.values())
    return hours


def paper_hours(results: dict, env_step_ms: float, eval_hours: float) -> dict | None:
    """:func:`project_paper` once every figure has a rate (and the posterior fit was
    timed); ``None`` for a partial run."""
    complete = all(best_modes(results).values()) and results.get("laplace")
    return project_paper(results, env_step_ms, eval_hours) if complete else None


def merge(paths: list[str], env_step_ms: float, eval_hours: float) -> dict:
    """One report of several runs' JSONs (e.g. each ``cudagraphs`` figure in its own
    process: a failed capture leaves the CUDA generator unusable for the next one)."""
    reports = [json.loads(open(p).read()) for p in paths]
    merged = dict(reports[0])
    results = merged["results"] = {k: dict(v) for k, v in reports[0]["results"].items()}
    for report in reports[1:]:
        for name, modes in report["results"].items():
            results.setdefault(name, {}).update(modes)
    merged["best_modes"] = best_modes(results)
    merged["paper_hours"] = paper_hours(results, env_step_ms, eval_hours)
    return merged
