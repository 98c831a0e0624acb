"""Checkpoints within an offline stage, and the line an interrupted offline phase ends with.

:class:`StageCheckpoints` and :func:`offline_interruption`.

An offline stage's update loop (the planner's ``L_VLB`` updates, the distillation rounds,
the actor-critic updates) saves the run every ``budget.offline_checkpoint_every`` offline
updates, counted over all stages (``O2ORun.offline_steps``), and when Ctrl-C or SIGTERM
stops it (:mod:`~torchrl_dual.recipe.o2o.interrupts`) or ``interrupt_at_offline_updates``
is reached: the run's state (weights, optimizers, counters, random state, logger) plus
``stage_progress``, the loop's own state (``run_updates``' optimizer, schedule, EMA and
log window; the update count) and the random state at that update. A resumed run skips
the finished stages and continues the loop from there; restoring the random state right
before the loop continues, it ends bitwise as the run never stopped. The state of a
stage in progress goes into the run's checkpoint only, never into a shared offline
phase (``offline_cache``), which is written when its stages are done.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

from torchrl_dual.checkpoint import RunCheckpoint, rng_state, set_rng_state
from torchrl_dual.recipe.o2o.interrupts import requested
from torchrl_dual.recipe.o2o.stage_clock import StageClock


class StageRun(Protocol):
    """What this module reads and writes of the run (an :class:`~torchrl_dual.recipe.O2ORun`)."""

    settings: Any  # the run's RecipeSettings
    checkpoint: RunCheckpoint
    current_stage: str | None  # the offline stage running
    stage_clock: StageClock | None  # its clock
    stage_progress: dict | None  # its loop's state, once saved within the stage
    offline_steps: int  # updates of the offline stages' loops
    stopped_at: str | None  # where an interrupt saved the stage

    def save(self) -> None:
        """Checkpoints the run (with ``stage_progress``)."""


class StageCheckpoints:
    """The running offline stage's checkpoints within it, for its update loop.

    An :class:`~torchrl_dual.objectives.UpdateCheckpoints`; ``O2ORun.stage_checkpoints``
    makes one.
    """

    def __init__(self, run: StageRun) -> None:
        self.run = run
        self.stage = run.current_stage

    def resume(self) -> dict[str, Any] | None:
        """The loop state saved within this stage, or ``None`` to start the loop at update 0.

        The random state of that moment is restored with it.
        """
        progress = self.run.stage_progress
        if progress is None or progress["stage"] != self.stage:
            return None
        set_rng_state(progress["rng"])
        return progress["loop"]

    def after_update(self, done: int, total: int, state: Callable[[], dict[str, Any]]) -> None:
        """Counts one offline update; saves the run when due, and stops it when asked.

        Saves the run with ``state()`` when ``budget.offline_checkpoint_every``
        divides the count, and when the run is to stop (a signal,
        ``interrupt_at_offline_updates``), then raises ``KeyboardInterrupt``.
        """
        run = self.run
        run.offline_steps += 1
        stop = requested() or run.offline_steps == run.settings.interrupt_at_offline_updates
        if stop or run.offline_steps % run.settings.budget.offline_checkpoint_every == 0:
            run.stage_clock.tick()  # the stage's seconds so far, continued on resume
            run.stage_progress = {
                "stage": self.stage,
                "done": done,
                "total": total,
                "loop": state(),
                "rng": rng_state(),
            }
            run.save()
        if stop:
            run.stopped_at = f"update {done}/{total} of offline stage {self.stage}"
            raise KeyboardInterrupt


def offline_interruption(run: StageRun) -> str:
    """The one line of an offline phase stopped by Ctrl-C or SIGTERM.

    Where it stopped and what the checkpoint holds. Stopped inside an update loop, the
    loop saved that update; elsewhere (between updates' loops, the Laplace fit, the
    offline evaluation) the last checkpoint is kept, and the step in progress runs again
    on resume.
    """
    if run.stopped_at is not None:
        said = f"interrupted at {run.stopped_at}; checkpoint saved."
    else:
        where = "the offline phase"
        if run.current_stage is not None:
            where = f"offline stage {run.current_stage}"
        kept = "its last checkpoint is kept" if run.checkpoint.exists() else "nothing saved yet"
        said = f"interrupted in {where}; {kept}."
    return f"{said} Continue with resume=true."
