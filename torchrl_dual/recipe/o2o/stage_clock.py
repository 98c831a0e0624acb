"""Wall-clock and CPU seconds per stage of a run: :class:`StageClock`."""

from __future__ import annotations

import time


class StageClock:
    """Adds the wall-clock and CPU seconds since its creation to a stage's totals.

    It adds them to ``seconds[name]`` and ``cpu_seconds[name]``, on top of what a
    resumed run had already spent: the run's ``stage_seconds`` and
    ``stage_cpu_seconds``.

    CPU seconds are this process's (``time.process_time``, all its threads). Other jobs
    on the same cores inflate them far less than wall time (measured on a 2-core machine
    under heavy load: a stage's CPU seconds ×1.2-1.4, its wall seconds ×2.9), so runs of
    the learning suite that ran side by side stay roughly comparable (``num_threads=1``:
    CPU ≈ wall on an idle core).

    Examples:
        >>> seconds, cpu_seconds = {"planner": 10.0}, {"planner": 9.0}
        >>> clock = StageClock(seconds, cpu_seconds, "planner")
        >>> clock.tick()
        >>> seconds["planner"] >= 10.0 and cpu_seconds["planner"] >= 9.0
        True
    """

    def __init__(self, seconds: dict[str, float], cpu_seconds: dict[str, float], name: str) -> None:
        self.seconds, self.cpu_seconds, self.name = seconds, cpu_seconds, name
        self.before = (seconds.get(name, 0.0), cpu_seconds.get(name, 0.0))
        self.start = (time.perf_counter(), time.process_time())

    def tick(self) -> None:
        """Writes the seconds so far (call it again to update them)."""
        wall, cpu = self.before
        self.seconds[self.name] = wall + time.perf_counter() - self.start[0]
        self.cpu_seconds[self.name] = cpu + time.process_time() - self.start[1]
