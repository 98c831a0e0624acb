"""Ctrl-C and SIGTERM stop a run alike, and an offline stage is checkpointed within.

A real SIGTERM during the offline phase of ``recipes/o2o.py`` (a subprocess) saves the
actor-critic loop at the update it reached, prints one line and exits 0; ``resume=true``
continues from that update and finishes. In-process, an offline stage stopped midway
(``interrupt_at_offline_updates``, in the planner, a distillation round or the
actor-critic updates) and resumed ends bitwise as the run never stopped, and a shared
offline phase (``offline_cache``) is published only once its stages are done.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from recipe_runner import REPO, TINY, WALL_CLOCK, checkpoint_state, run_recipe, succeeded

from torchrl_dual.checkpoint import state_differences
from torchrl_dual.recipe import CONFIG_DIR, DualLearner, compose_checked, run_o2o
from torchrl_dual.recipe.o2o.interrupts import held, requested, signals_as_interrupts

pytestmark = pytest.mark.long_running(seconds=60)  # starts first under xdist


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("interrupt_data")


# ----------------------------------------------------------------------------- the handlers
def _sigterm_to_self() -> None:
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(0.01)  # Python runs the handler between two bytecodes of this thread


def test_sigterm_is_ctrl_c_inside_the_block_and_waits_for_the_end_of_a_held_one():
    with signals_as_interrupts():
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"):
            _sigterm_to_self()
        with held():  # an update loop: noted, taken at the update's end
            _sigterm_to_self()
            assert requested() and not requested()
        with pytest.raises(KeyboardInterrupt, match="SIGTERM"), held():
            _sigterm_to_self()  # not taken: raised when the block ends
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_sigterm_before_the_run_begins_ends_in_one_line_and_exit_130(monkeypatch, capsys):
    """While the command line is checked (before Hydra and the run), a SIGTERM ends the
    program with one line, not with the bare exit 143 of Python's default handler."""
    from torchrl_dual.recipe import cli

    def checked_then_signalled(config_dir):
        _sigterm_to_self()

    monkeypatch.setattr(cli, "check_command_line", checked_then_signalled)
    monkeypatch.setattr(sys, "argv", ["o2o.py", "budget=smoke"])
    with pytest.raises(SystemExit) as stop:
        cli.main()
    assert stop.value.code == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "interrupted (SIGTERM) outside the run's steps (while it was set up); no run state "
        "was saved. Start it again."
    ]
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_an_ignored_sigint_stays_ignored():
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with signals_as_interrupts():
            assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
            assert signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL
    finally:
        signal.signal(signal.SIGINT, previous)


# ----------------------------------------------------------------------------- a real SIGTERM
def test_sigterm_in_the_offline_phase_saves_the_update_it_reached_and_resume_continues(
    cache_dir, tmp_path
):
    out = tmp_path / "run"
    overrides = [
        *TINY,
        "algo=iql",
        "budget.offline_updates=1000",
        "budget.offline_checkpoint_every=100",
    ]
    cmd = [
        sys.executable,
        "recipes/o2o.py",
        *overrides,
        f"output_dir={out}",
        f"data_cache_dir={cache_dir}",
    ]
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}
    proc = subprocess.Popen(
        cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:  # the first checkpoint within the actor-critic stage: update 100 of 1000
        while not (out / "checkpoint.pt").exists() and proc.poll() is None:
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 0, f"exit {proc.returncode}\n{stdout[-2000:]}\n{stderr[-3000:]}"
    assert "Traceback" not in stdout + stderr
    progress = checkpoint_state(out)["stage_progress"]
    done = progress["done"]
    assert progress["stage"] == "actor_critic" and 100 <= done < 1000
    line = (
        f"[iql] interrupted at update {done}/1000 of offline stage actor_critic; checkpoint "
        "saved. Continue with resume=true."
    )
    assert stdout.splitlines()[-1] == line
    assert not (out / "summary.json").exists()

    resumed = succeeded(run_recipe(out, cache_dir, *overrides, "resume=true"))
    assert f"[iql] actor_critic: continues from update {done}/1000" in resumed.stdout
    final = checkpoint_state(out)
    assert final["stage_progress"] is None and final["frames"] == 100
    assert final["offline_steps"] == 1000 and (out / "summary.json").exists()


# ----------------------------------------------------------------------------- bitwise resume
DUAL_OFFLINE = (
    "budget.planner_updates=6",
    "budget.distill_updates=[2,2,2,2,2]",
    "budget.offline_updates=6",
    "budget.offline_checkpoint_every=4",
)
"""22 offline updates: the planner's 1-6, distillation's 7-16, the actor-critic's 17-22."""


def dual_config(output_dir: Path, cache_dir: Path, *extra: str):
    return compose_checked(
        CONFIG_DIR,
        [*TINY, *DUAL_OFFLINE, f"output_dir={output_dir}", f"data_cache_dir={cache_dir}",
         *extra],
    )  # fmt: skip


@pytest.fixture(scope="module")
def whole_run(tmp_path_factory, cache_dir):
    """The run never interrupted."""
    return run_o2o(dual_config(tmp_path_factory.mktemp("whole"), cache_dir), DualLearner)


@pytest.mark.parametrize(
    ("stop_at", "stage", "done"),
    [(3, "planner", "3/6"), (9, "distillation", "3/10"), (19, "actor_critic", "3/6")],
)
def test_an_offline_stage_stopped_midway_and_resumed_ends_bitwise_as_the_whole_run(
    stop_at, stage, done, whole_run, cache_dir, tmp_path, capsys
):
    out, shared = tmp_path / "run", tmp_path / "offline_cache"
    first = run_o2o(
        dual_config(
            out, cache_dir, f"interrupt_at_offline_updates={stop_at}", f"offline_cache={shared}"
        ),
        DualLearner,
    )
    assert capsys.readouterr().out.splitlines()[-1] == (
        f"[dual] interrupted at update {done} of offline stage {stage}; checkpoint saved. "
        "Continue with resume=true."
    )
    assert first.offline_steps == stop_at and first.frames == 0
    saved = checkpoint_state(out)
    assert saved["stage_progress"]["stage"] == stage and stage not in saved["stages_done"]
    # the unfinished shared offline phase is not published (its lock file is all there is)
    assert [p.name for p in shared.glob("*/*")] == ["lock"]

    second = run_o2o(
        dual_config(out, cache_dir, "resume=true", f"offline_cache={shared}"), DualLearner
    )
    assert f"[dual] {stage}: continues from update {done}" in capsys.readouterr().out
    assert second.frames == 100 and second.stage_progress is None
    assert len(list(shared.glob("*/offline_phase.pt"))) == 1  # published once finished
    differ = state_differences(whole_run.state(), second.state(), ignore=WALL_CLOCK)
    assert differ == [], f"the resumed run differs at {differ[:10]}"
