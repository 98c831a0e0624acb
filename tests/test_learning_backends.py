"""``benchmarks.learning.backends.run_recipe`` on this machine: what a suite run's files show
while it runs."""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path

from benchmarks.learning import backends as learning_backends

REPO = Path(__file__).resolve().parents[1]

# prints a line, then waits (at most 30 s) for the test to answer through a file
_CHILD = """
import pathlib, sys, time
print("stage: planner")
answer = pathlib.Path(sys.argv[1])
for _ in range(300):
    if answer.exists():
        break
    time.sleep(0.1)
"""


def test_a_running_recipe_s_output_reaches_stdout_txt_before_it_exits(tmp_path, monkeypatch):
    """The recipe's stage lines (``print``) must be readable in ``stdout.txt`` while the
    run goes on (an hour for a Cal-QL run), not only when the child exits: the child's
    stdout is a file, which Python would buffer in 8 KiB blocks."""
    monkeypatch.delenv("PYTHONUNBUFFERED", raising=False)  # as in a user's shell
    answer, run_dir = tmp_path / "seen", tmp_path / "run"
    command = [sys.executable, "-c", _CHILD, str(answer)]
    outcome = {}
    runner = threading.Thread(
        target=lambda: outcome.update(
            learning_backends.run_recipe(command, str(run_dir), str(tmp_path))
        )
    )
    runner.start()
    stdout, seen = run_dir / "stdout.txt", ""
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and "stage: planner" not in seen:
        time.sleep(0.1)
        seen = stdout.read_text() if stdout.exists() else ""
    answer.touch()  # lets the child exit, seen or not
    runner.join(timeout=60)
    assert seen == "stage: planner\n"
    assert outcome["error"].startswith("exit 0, no summary.json")


def test_a_recipe_handles_sigint_when_the_driver_ignores_it():
    """A driver run in the background of a non-interactive shell (``learning.py ... &``)
    ignores SIGINT; its recipes must not inherit that, or Ctrl-C / ``ray.cancel`` could not
    make them checkpoint."""
    import signal
    import subprocess

    probe = [sys.executable, "-c", "import signal; print(repr(signal.getsignal(signal.SIGINT)))"]
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        plain = subprocess.run(probe, capture_output=True, text=True).stdout
        recipe = subprocess.run(
            probe, capture_output=True, text=True, preexec_fn=learning_backends._recipe_preexec()
        ).stdout
    finally:
        signal.signal(signal.SIGINT, previous)
    assert "SIG_IGN" in plain  # what a child inherits without the reset
    assert recipe.strip() == "<built-in function default_int_handler>"
