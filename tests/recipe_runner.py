"""Running ``recipes/o2o.py`` and the benchmark scripts from tests, as a user would.

``run_recipe`` starts one smoke-budget run and returns what a user would see of it (exit
code, stdout, stderr) as a :class:`subprocess.CompletedProcess`. By default the run goes
through the command line's own steps in this process (:func:`check_command_line`'s
composition and checks, then :func:`hydra_task`), which saves each run the ≈ 8 CPU-s
of starting Python and importing torch, TorchRL and Hydra. ``cli=True`` runs the real
``python recipes/o2o.py`` instead, so ``@hydra.main`` stays under test
(``test_o2o.py``'s PointMaze smoke run, ``test_config_errors.py``'s command-line tests).
``run_script`` and ``run_module`` run a script (``python <path>``) or a benchmark
(``python -m benchmarks.<group>.<name>``) in this process the same way. ``succeeded`` and
``failed`` assert on how a run ended (``failed``: exit 2, one
``error:`` line, no traceback). ``TINY`` is a cut-down smoke budget for in-process runs of
every algorithm, ``checkpoint_state`` reads a run's checkpoint and ``WALL_CLOCK`` names
what two runs of one seed may differ in.
"""

from __future__ import annotations

import contextlib
import io
import os
import random
import runpy
import subprocess
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from torchrl_dual.recipe import CONFIG_DIR

REPO = Path(__file__).resolve().parents[1]

TINY = (
    "budget=smoke",
    "env=frozenlake",
    "budget.dataset_transitions=1000",
    "budget.network_width=16",
    "budget.batch_size=32",  # dacer estimates its entropy on 32 states of a batch
    "budget.planner_updates=4",
    "budget.distill_updates=[2,2,2,2,2]",
    "budget.offline_updates=4",
    "budget.online_frames=100",
    "budget.frames_per_batch=50",
    "budget.laplace_refit_every=10",
    "budget.eval_every=100",
    "budget.eval_episodes=1",
    "budget.checkpoint_every=50",
    "progress=false",
    "num_threads=1",
)
"""Frozen-Lake at a cut-down smoke budget: every algorithm in seconds, in-process."""

WALL_CLOCK = ("stage_seconds", "stage_cpu_seconds", "logger")
"""What two runs of the same seed may differ in: the stages' times and the logger's paths."""


def compose_smoke(tmp_path: Path, *overrides: str):
    """The validated config of a ``budget=smoke`` run writing under ``tmp_path / "run"``,
    with ``overrides`` (``compose_checked``, as the command line composes it)."""
    from torchrl_dual.recipe import compose_checked

    return compose_checked(
        CONFIG_DIR,
        [f"output_dir={tmp_path / 'run'}", "budget=smoke", "progress=false", *overrides],
    )


@contextlib.contextmanager
def standin_minari_datasets(root: Path, sizes: dict[str, tuple[int, int]]) -> Iterator[Path]:
    """``MINARI_DATASETS_PATH`` set to ``root`` holding a stand-in data set per
    ``{dataset_id: (episodes, steps per episode)}``
    (:func:`~torchrl_dual.data.minari_standins.write_standin_dataset`), restored after."""
    from torchrl_dual.data.minari_standins import write_standin_dataset

    previous = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        for dataset_id, (episodes, steps) in sizes.items():
            write_standin_dataset(dataset_id, episodes, steps)
        yield root
    finally:
        if previous is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = previous


def checkpoint_state(output_dir: Path) -> dict:
    """The state saved in ``output_dir/checkpoint.pt``."""
    payload = torch.load(output_dir / "checkpoint.pt", map_location="cpu", weights_only=False)
    return payload["state"]


def run_recipe(
    output_dir: Path, cache_dir: Path, *overrides: str, cli: bool = False
) -> subprocess.CompletedProcess:
    """``python recipes/o2o.py budget=smoke ...`` from the repo root; never raises for
    a run that ends with an exit code (an unexpected exception in-process propagates,
    with its traceback, to the test)."""
    args = [
        "budget=smoke",
        f"output_dir={output_dir}",
        f"data_cache_dir={cache_dir}",
        "progress=false",
        "num_threads=1",  # tiny networks: one thread avoids OpenMP contention
        *overrides,
    ]
    if cli:
        cmd = [sys.executable, "recipes/o2o.py", *args]
        env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}
        return subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    return _run_in_process(args)


def _run_in_process(args: list[str]) -> subprocess.CompletedProcess:
    """The command line's two steps (``check_command_line``, then the Hydra task on the
    config it composed) with stdout and stderr captured; torch's thread count and the
    torch, numpy and python RNG states are restored afterwards, so that the run leaves
    the test process as it found it."""
    from torchrl_dual.recipe import compose_checked, hydra_task
    from torchrl_dual.recipe.settings.errors import user_errors

    threads, code = torch.get_num_threads(), 0
    np_state, py_state = np.random.get_state(), random.getstate()
    with _in_repo_captured() as (stdout, stderr), torch.random.fork_rng():
        try:
            with user_errors(debug=False):
                cfg = compose_checked(CONFIG_DIR, args)
            hydra_task(cfg)
        except SystemExit as exit_:
            code = _exit_code(exit_)
        finally:
            torch.set_num_threads(threads)
            np.random.set_state(np_state)
            random.setstate(py_state)
    return subprocess.CompletedProcess(
        ["o2o.py", *args], code, stdout.getvalue(), stderr.getvalue()
    )


def run_script(script: str, *args: str) -> subprocess.CompletedProcess:
    """``python <script> <args>`` from the repo root, run in this process (``runpy``,
    with ``sys.argv`` and ``sys.path[0]`` as Python would set them) to save the start-up
    of a new interpreter; the exit code comes from ``SystemExit``."""
    path = REPO / script
    return _run_main(
        [script, *args],
        [str(path), *args],
        str(path.parent),
        lambda: runpy.run_path(str(path), run_name="__main__"),
    )


def run_console_script(name: str, *args: str) -> subprocess.CompletedProcess:
    """The installed console script ``name`` (``torchrl-dual``) with ``args``: its entry
    point as the package metadata declares it, run in this process as :func:`run_script`
    runs a script."""
    from importlib.metadata import entry_points

    (entry,) = entry_points(group="console_scripts", name=name)
    return _run_main([name, *args], [name, *args], str(REPO), lambda: entry.load()())


def run_module(module: str, *args: str) -> subprocess.CompletedProcess:
    """``python -m <module> <args>`` from the repo root (a benchmark:
    ``benchmarks.speed.latency``), run in this process as :func:`run_script` runs a
    script (``sys.path[0]`` the repo root, as ``-m`` sets it)."""
    return _run_main(
        ["-m", module, *args],
        [module, *args],
        str(REPO),
        lambda: _run_module_quietly(module),
    )


def _run_module_quietly(module: str) -> None:
    """``runpy.run_module`` as ``-m`` runs it, without the warning that the test's own
    import of the module (``from benchmarks.speed import families``) would give."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", "'.*' found in sys.modules", RuntimeWarning)
        runpy.run_module(module, run_name="__main__", alter_sys=True)


def _run_main(command: list[str], argv: list[str], path0: str, run) -> subprocess.CompletedProcess:
    """Runs ``run()`` with ``sys.argv = argv`` and ``path0`` first on ``sys.path``, in the
    repo root, output captured; both restored after."""
    saved_argv, sys_path, code = sys.argv, list(sys.path), 0
    sys.argv, sys.path[:0] = argv, [path0]
    try:
        with _in_repo_captured() as (stdout, stderr):
            run()
    except SystemExit as exit_:
        code = _exit_code(exit_)
    finally:
        sys.argv, sys.path[:] = saved_argv, sys_path
    return subprocess.CompletedProcess(command, code, stdout.getvalue(), stderr.getvalue())


@contextlib.contextmanager
def _in_repo_captured() -> Iterator[tuple[io.StringIO, io.StringIO]]:
    """The working directory set to the repo root, stdout and stderr captured."""
    stdout, stderr = io.StringIO(), io.StringIO()
    with (
        contextlib.chdir(REPO),
        contextlib.redirect_stdout(stdout),
        contextlib.redirect_stderr(stderr),
    ):
        yield stdout, stderr


def _exit_code(exit_: SystemExit) -> int:
    """The process exit code Python gives ``exit_``: an int as is, None 0, anything else 1."""
    if isinstance(exit_.code, int):
        return exit_.code
    return 0 if exit_.code is None else 1


def succeeded(proc: subprocess.CompletedProcess) -> subprocess.CompletedProcess:
    assert proc.returncode == 0, f"exit {proc.returncode}\n{proc.stdout}\n{proc.stderr[-4000:]}"
    return proc


def failed(proc: subprocess.CompletedProcess) -> str:
    """Asserts exit code 2 with one ``error:`` line on stderr and no traceback; returns it."""
    out = proc.stdout + proc.stderr
    assert proc.returncode == 2, f"expected exit 2, got {proc.returncode}\n{out[-4000:]}"
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, proc.stderr[-4000:]
    assert "Traceback" not in out
    return errors[0]
