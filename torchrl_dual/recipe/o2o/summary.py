"""What a finished recipe run measured: ``summary.json``, the learning curve, the scores.

``summary.json`` is one small file per run (``python -m benchmarks.learning`` collects
them): the evaluation history, the online signals per collected batch (DUAL's epistemic
std and shift distance), the wall time of every stage and of the online phase, whether
the offline stages came from a shared offline phase, and the resolved config.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Protocol

from torchrl_dual.recipe.o2o.loggers import logs_text
from torchrl_dual.recipe.o2o.plots import plot_learning_curve
from torchrl_dual.recipe.settings.structured import RecipeSettings


class FinishedRun(Protocol):
    """What this module reads of a run (a :class:`~torchrl_dual.recipe.O2ORun`)."""

    settings: RecipeSettings
    config: dict  # the resolved config, plain containers
    name: str
    output_dir: Path
    learner: Any
    history: list[dict]
    online_signals: list[dict]
    stage_seconds: dict[str, float]
    stage_cpu_seconds: dict[str, float]
    shared_offline: bool
    frames: int
    updates: int

    def say(self, text: str) -> None:
        """Prints ``text`` on one line, prefixed by the run's name."""


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
    settings = run.settings
    seconds = {name: round(float(value), 3) for name, value in run.stage_seconds.items()}
    offline = sum(value for name, value in seconds.items() if name != "online")
    cpu = {name: round(float(value), 3) for name, value in run.stage_cpu_seconds.items()}
    return {
        "algo": settings.algo,
        "env": str(settings.env.name),
        "seed": settings.seed,
        "budget": str(settings.budget.name),
        "shift": str(getattr(settings.env, "shift", "none")),
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
        "config": run.config,
    }


def write_summary(run: FinishedRun, path: Path) -> Path:
    """Writes :func:`run_summary` to ``path`` atomically; returns ``path``."""
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(run_summary(run), indent=1, default=float))
    os.replace(tmp, path)
    return path


def report_finished_run(run: FinishedRun) -> None:
    """Writes ``summary.json`` and the learning curve into the run's directory, prints both.

    Also prints the normalized scores after the offline phase and at the end, and where
    the logger wrote.
    """
    write_summary(run, run.output_dir / "summary.json")
    png = plot_learning_curve(
        run.history,
        run.output_dir / "learning_curve.png",
        title=f"{run.learner.title} on {run.settings.env.name}",
        signals=run.online_signals,
    )
    offline = next((h["normalized_score"] for h in run.history if h["label"] == "offline"), None)
    run.say("done.")
    if offline is not None:
        run.say(f"normalized score after the offline phase: {score_text(offline)}")
    if run.history:
        final = run.history[-1]["normalized_score"]
        run.say(f"normalized score at the end of the online phase: {score_text(final)}")
    run.say(logs_text(run.settings.logger, run.output_dir / "logs", run.name))
    run.say(f"learning curve: {png}")
