"""One writer per run directory (``torchrl_dual/recipe/o2o/run_lock.py``): a second run
into a directory a live run holds is refused with one line naming the directory and the
process (as the command line and as ``run_o2o``), a fresh run and a ``resume=true`` run
alike; a run killed without releasing its lock leaves a stale lock the next run takes."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from recipe_runner import REPO, TINY, failed, run_recipe, run_script, succeeded

from torchrl_dual.recipe.o2o.run_lock import (
    LOCK_NAME,
    acquire_run_directory,
    release_run_directory,
    run_directory_lock,
)
from torchrl_dual.recipe.settings.errors import UserError

# an IQL run whose offline phase outlasts the test: it holds its directory until killed
LONG_RUN = (*TINY, "algo=iql", "budget.offline_updates=1000000")


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("data_cache")


def _holder(path) -> dict | None:
    try:
        return json.loads((path / LOCK_NAME).read_text())
    except (OSError, ValueError):
        return None


@pytest.fixture
def running(tmp_path):
    """A recipe run (``python recipes/o2o.py``) that holds ``tmp_path / "run"``, SIGKILLed
    at the end of the test: its process and its output directory."""
    out = tmp_path / "run"
    cmd = [sys.executable, "recipes/o2o.py", *LONG_RUN, f"output_dir={out}",
           f"data_cache_dir={tmp_path / 'cache_a'}"]  # fmt: skip
    env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        while (_holder(out) or {}).get("pid") != proc.pid:  # taken before Hydra starts
            assert proc.poll() is None, proc.stderr.read()[-3000:]
            time.sleep(0.02)
        yield proc, out
    finally:
        proc.kill()
        proc.wait()


def test_a_second_run_into_a_held_directory_is_refused_naming_it_and_the_process(
    running, cache_dir
):
    proc, out = running
    text = f"output_dir={out}: in use by process {proc.pid} on {socket.gethostname()} ("
    overrides = [*LONG_RUN, f"output_dir={out}", f"data_cache_dir={cache_dir}"]
    # the command line (the lock is taken before Hydra writes into the directory)
    second = failed(run_script("recipes/o2o.py", *overrides))
    assert second.startswith(f"error: {text}")
    assert second.endswith("; wait for that run to end or choose another output_dir")
    # run_o2o, as a resume=true run (the command line's steps in this process)
    resumed = failed(run_recipe(out, cache_dir, *LONG_RUN, "resume=true"))
    assert resumed.startswith(f"error: {text}")
    assert proc.poll() is None  # the first run goes on, its files untouched
    assert not (out / "checkpoint.pt").exists() and not (out / "summary.json").exists()


def test_a_killed_run_leaves_a_stale_lock_the_next_run_takes(running, cache_dir):
    proc, out = running
    proc.send_signal(signal.SIGKILL)  # no chance to release its lock
    proc.wait()
    assert _holder(out)["pid"] == proc.pid  # the file stays, naming a process that is gone
    done = succeeded(run_recipe(out, cache_dir, *TINY, "algo=iql", "resume=true"))
    assert "no checkpoint" in done.stdout and (out / "summary.json").exists()
    assert not (out / LOCK_NAME).exists()  # released at the end of the run


def test_a_lock_file_naming_a_dead_process_is_stale(tmp_path):
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    (tmp_path / LOCK_NAME).write_text(json.dumps({"pid": int(gone.stdout), "host": "h"}))
    with run_directory_lock(tmp_path):
        assert _holder(tmp_path)["pid"] == os.getpid()
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_process_holds_its_lock_once_and_the_block_that_took_it_releases_it(tmp_path):
    assert acquire_run_directory(tmp_path) is True
    with run_directory_lock(tmp_path):  # held already: neither taken nor released here
        assert acquire_run_directory(tmp_path / ".." / tmp_path.name) is False
    assert (tmp_path / LOCK_NAME).exists()
    release_run_directory(tmp_path)
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_lock_held_elsewhere_is_refused_by_acquire(tmp_path):
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from torchrl_dual.recipe.o2o.run_lock import "
         f"acquire_run_directory as a; a({str(tmp_path)!r}); print('held', flush=True); "
         "sys.stdin.read()"],
        cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)}, stdin=subprocess.PIPE,
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline() == "held\n"
        with pytest.raises(UserError, match=rf"in use by process {holder.pid} on "):
            acquire_run_directory(tmp_path)
    finally:
        holder.stdin.close()
        holder.wait()
    assert acquire_run_directory(tmp_path) is True  # its end released it
    release_run_directory(tmp_path)


def test_a_forked_child_of_the_holder_does_not_keep_its_lock(tmp_path):
    """A collector's worker forked by a run that then dies does not hold the directory."""
    script = (
        "import os, sys; from torchrl_dual.recipe.o2o.run_lock import acquire_run_directory; "
        f"acquire_run_directory({str(tmp_path)!r}); child = os.fork()\n"
        "if child == 0: sys.stdin.read(); os._exit(0)\n"
        "print(child, flush=True); os._exit(0)"
    )
    holder = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)})  # fmt: skip
    try:
        child = int(holder.stdout.readline())
        holder.wait()  # the holder is gone, its forked child lives on
        os.kill(child, 0)
        assert acquire_run_directory(tmp_path) is True
        release_run_directory(tmp_path)
    finally:
        holder.stdin.close()
