"""Wall-clock and CPU seconds per stage of a run: :class:`StageClock`."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.run import O2ORun


class StageClock:
    """Adds the wall-clock and CPU seconds since its creation to ``run.stage_seconds[name]``
    and ``run.stage_cpu_seconds[name]`` (on top of what a resumed run had already spent).

    CPU seconds are this process's (``time.process_time``, all its threads). Other jobs
    on the same cores inflate them far less than wall time (measured on a 2-core machine
    under heavy load: a stage's CPU seconds ×1.2-1.4, its wall seconds ×2.9), so runs of
    the learning suite that ran side by side stay roughly comparable (``num_threads=1``:
    CPU ≈ wall on an idle core).
    """

    def __init__(self, run: O2ORun, name: str) -> None:
        self.run, self.name = run, name
        self.before = (run.stage_seconds.get(name, 0.0), run.stage_cpu_seconds.get(name, 0.0))
        self.start = (time.perf_counter(), time.process_time())

    def tick(self) -> None:
        wall, cpu = self.before
        self.run.stage_seconds[self.name] = wall + time.perf_counter() - self.start[0]
        self.run.stage_cpu_seconds[self.name] = cpu + time.process_time() - self.start[1]
