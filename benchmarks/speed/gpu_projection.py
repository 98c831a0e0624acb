"""The ``budget=paper`` wall time projected from ``gpu_throughput.py``'s rates, and the
merge of several of its JSON reports into one.

The projection of one ``budget=paper`` AntMaze run (1M planner updates, 5 × 20k
distillation updates, 1M offline and 1M online actor-critic updates (``PAPER``'s
``utd_ratio``), 1M online steps, a posterior refit every 10k updates over all transitions) takes, for each update and acting
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
    (2.778, 12.07)
    >>> del results["laplace"]
    >>> print(paper_hours(results, env_step_ms=3.9, eval_hours=0.4))  # incomplete
    None
"""

from __future__ import annotations

import json

PAPER = {
    "planner_updates": 1_000_000, "distill_updates": [20_000] * 5, "offline_updates": 1_000_000,
    "online_frames": 1_000_000, "frames_per_batch": 1000, "utd_ratio": 1.0,
    "laplace_refit_every": 10_000, "eval_every": 50_000, "eval_episodes": 100,
    "dataset_transitions": 1_000_000,
}  # fmt: skip
"""``budget=paper`` (``torchrl_dual/recipe/config/budget/paper.yaml``) and DUAL's online
``utd_ratio`` there (CORL's one update per env step: ``settings/references.py``
``BUDGET_SETTINGS``): what :func:`project_paper` and :func:`project_from_probe` multiply the
measured rates by."""

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


def _refit_transitions(online_updates: float) -> float:
    """Transitions the posterior refits read: ``D_offline`` once after the offline phase,
    then ``D_offline`` and half the online frames (on average) every refit."""
    p = PAPER
    refits = online_updates / p["laplace_refit_every"]
    return p["dataset_transitions"] + refits * (p["dataset_transitions"] + p["online_frames"] / 2)


def project_paper(results: dict, env_step_ms: float, eval_hours: float) -> dict[str, float]:
    """Hours of one ``budget=paper`` AntMaze run from the measured rates (see the module
    docstring for the terms and the CPU-bound inputs)."""
    p = PAPER
    online_updates = p["online_frames"] * p["utd_ratio"]
    hours = {
        "planner": p["planner_updates"] / best(results, "planner")[1],
        "distillation": sum(p["distill_updates"]) / best(results, "distillation")[1],
        "actor_critic": p["offline_updates"] / best(results, "actor_critic")[1],
        # a fit after the offline phase, then every 10k online updates over 1M..2M
        # transitions: 1M + 100 x 1.5M = 151M transitions at 1M online updates
        "laplace": _refit_transitions(online_updates)
        / 1000
        / results["laplace"]["eager"]["per_second_1k"],
        "online_updates": online_updates / best(results, "actor_critic")[1],
        "online_steps": p["online_frames"] * (env_step_ms / 1000 + 1 / best(results, "act_b1")[1]),
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
    merged["merged_from"] = [report.get("provenance") for report in reports]  # where measured
    merged["best_modes"] = best_modes(results)
    merged["paper_hours"] = paper_hours(results, env_step_ms, eval_hours)
    return merged


def project_from_probe(probe: dict) -> dict:
    """Hours of one ``budget=paper`` AntMaze run from an end-to-end probe's figures only
    (``e2e_probe.py``); every input is labelled with where and when it was measured.

    The online phase is 1M frames at the probe's cost per frame (collection, acting and
    its updates at ``utd_ratio``), plus the refits (a fit of ``D_offline`` after the
    offline phase, then one every 10k online updates over 1M..2M transitions: 151M
    transitions in all at 1M online updates) and 21 evaluations of 100 episodes (after the offline phase and
    every 50k frames), each at the probe's measured cost. A probe at another ``utd_ratio``
    than the paper's is refused.

    Examples:
        >>> probe = {"measured": {"machine": "m", "date": "d", "command": "c"}, "rates": {
        ...     "planner_updates_per_s": 500.0, "distill_updates_per_s": 250.0,
        ...     "offline_updates_per_s": 400.0, "laplace_s_per_1k_transitions": 0.01,
        ...     "evaluation_s": 30.0, "evaluation_episodes": 100,
        ...     "online_s_per_frame": 0.002, "online_utd_ratio": 1.0}}
        >>> hours = project_from_probe(probe)
        >>> round(hours["planner"], 3), round(hours["total"], 2)
        (0.556, 2.51)
        >>> hours["inputs"]["online_s_per_frame"]["measured"]["machine"]
        'm'
    """
    r, p = probe["rates"], PAPER
    if abs(r["online_utd_ratio"] - p["utd_ratio"]) > 1e-9:
        raise ValueError(
            f"the probe ran online.utd_ratio={r['online_utd_ratio']}, budget=paper's DUAL "
            f"runs {p['utd_ratio']}: rerun the probe at the paper's ratio."
        )
    refit_transitions = _refit_transitions(p["online_frames"] * p["utd_ratio"])
    evaluations = 1 + p["online_frames"] // p["eval_every"]
    per_episode = r["evaluation_s"] / r["evaluation_episodes"]
    seconds = {
        "planner": p["planner_updates"] / r["planner_updates_per_s"],
        "distillation": sum(p["distill_updates"]) / r["distill_updates_per_s"],
        "actor_critic": p["offline_updates"] / r["offline_updates_per_s"],
        "laplace": refit_transitions / 1000 * r["laplace_s_per_1k_transitions"],
        "online": p["online_frames"] * r["online_s_per_frame"],
        "evaluation": evaluations * p["eval_episodes"] * per_episode,
    }
    hours: dict = {k: v / 3600 for k, v in seconds.items()}
    hours["total"] = sum(hours.values())
    hours["inputs"] = {k: {"value": v, "measured": probe["measured"]} for k, v in r.items()}
    return hours
