"""``summary.json``: what a finished recipe run measured, for the learning suite.

One small file per run (``python -m benchmarks.learning`` collects them): the evaluation history,
the online signals per collected batch (DUAL's epistemic std and shift distance), the wall time of every stage and of the online phase, whether the offline stages came from
a shared offline phase, and the resolved config.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Protocol

from omegaconf import DictConfig, OmegaConf


class FinishedRun(Protocol):
    """What :func:`run_summary` reads of a run (a :class:`~torchrl_dual.recipe.O2ORun`)."""

    cfg: DictConfig
    history: list[dict]
    online_signals: list[dict]
    stage_seconds: dict[str, float]
    stage_cpu_seconds: dict[str, float]
    shared_offline: bool
    frames: int
    updates: int


NO_REFERENCES = "n/a (the data set has no reference returns; set env.reference_returns)"


def score_text(score: float) -> str:
    """A normalized score for the console, or why there is none (NaN: no references).

    Examples:
        >>> score_text(57.25), score_text(float("nan"))[:3]
        ('57.2', 'n/a')
    """
    return NO_REFERENCES if math.isnan(score) else f"{score:.1f}"


def run_summary(run: FinishedRun) -> dict:
    """The summary of ``run`` as a JSON-ready dict.

    ``offline_seconds`` sums the offline stages (``offline_eval`` included; stages loaded
    from a shared offline phase count with the time their first run spent on them), and
    ``wall_seconds`` adds the online phase: the cost of one run on its own.
    ``stage_cpu_seconds`` and ``cpu_seconds`` are the same in CPU seconds of the run's
    process (:class:`~torchrl_dual.recipe.o2o.stage_clock.StageClock`), which runs sharing the
    cores do not inflate.
    """
    cfg = run.cfg
    seconds = {name: round(float(value), 3) for name, value in run.stage_seconds.items()}
    offline = sum(value for name, value in seconds.items() if name != "online")
    cpu = {name: round(float(value), 3) for name, value in run.stage_cpu_seconds.items()}
    return {
        "algo": str(cfg.algo),
        "env": str(cfg.env.name),
        "seed": int(cfg.seed),
        "budget": str(cfg.budget.name),
        "shift": str(cfg.env.get("shift", "none")),
        "history": run.history,
        "online_signals": run.online_signals,
        "stage_seconds": seconds,
        "offline_seconds": round(offline, 3),
        "wall_seconds": round(offline + seconds.get("online", 0.0), 3),
        "stage_cpu_seconds": cpu,
        "cpu_seconds": round(sum(cpu.values()), 3),
        "shared_offline": bool(run.shared_offline),
        "frames": int(run.frames),
        "updates": int(run.updates),
        "config": OmegaConf.to_container(cfg, resolve=True),
    }


def write_summary(run: FinishedRun, path: Path) -> Path:
    """Writes :func:`run_summary` to ``path`` atomically; returns ``path``."""
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(run_summary(run), indent=1, default=float))
    os.replace(tmp, path)
    return path
