"""Where the learning suite's runs execute: this machine's cores or a Ray cluster.

``python -m benchmarks.learning --backend <name>`` picks an entry of :data:`BACKENDS`. A backend
takes the queue (leaders of each offline-sharing group first) and yields ``(run, outcome)``
as the runs finish; the driver turns each finished run's ``summary.json`` into its compact
JSON, so both backends write the same files in the same way.

- ``local``: ``--jobs`` threads, each running one ``python recipes/o2o.py`` subprocess.
- ``ray``: one Ray task per run (``@ray.remote(num_cpus=1, num_gpus=--gpus-per-run)``, the
  same subprocess on whichever node has a free CPU, and GPU if asked), submitted in the queue's order. A task lost with its
  node is retried (``--ray-retries``); the retry finds the run's ``checkpoint.pt`` under
  ``--out`` and continues it with ``resume=true``, so ``--out`` must be storage that every
  node mounts at the same path (checked: every task reads a token the driver wrote there).
  Every node needs this repository at the same path and the same Python environment.

Runs of one offline-sharing group wait for the first of them on the offline cache's
``fcntl`` lock (``torchrl_dual/recipe/o2o/offline_cache.py``), across nodes as long as the
shared file system supports ``flock`` (NFSv4 and Lustre do). See ``docs/scale-out.md``.
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import os
import platform
import signal
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from typing import Any, Protocol

from benchmarks.learning.cells import Run
from benchmarks.provenance import cpu_model, provenance


class Suite(Protocol):
    """What a backend reads of the suite (``learning.Suite``)."""

    args: argparse.Namespace

    def command(self, run: Run) -> list[str]: ...

    def run_dir(self, run: Run) -> Path: ...


REPO = Path(__file__).resolve().parents[2]
INSTALL_RAY = "pip install 'torchrl-dual[ray]'"
SHARED_TOKEN = ".suite-shared-token"
"""File under ``--out`` that every Ray task reads to check that ``--out`` is shared."""

Outcome = dict[str, Any]
"""One run's end: ``error`` (``""`` on success), ``seconds``, the ``machine`` it ran on and
its ``provenance`` there (:func:`benchmarks.provenance.provenance`: host, CPU, commit, dirty
flag, read on the node when the run starts)."""


def machine() -> str:
    """This node: platform, CPU model and count, the torch / torchrl versions (not
    imported).

    Examples:
        >>> "torch 2." in machine() and "CPUs" in machine()
        True
    """
    versions = ", ".join(f"{n} {importlib.metadata.version(n)}" for n in ("torch", "torchrl"))
    model = cpu_model()
    cpus = f"{os.cpu_count()} CPUs" + (f" ({model})" if model else "")
    return f"{platform.platform()}, {cpus}, {versions}"


def run_recipe(
    command: list[str], run_dir: str, cwd: str, shared_token: tuple[str, str] | None = None
) -> Outcome:
    """Runs (or continues) one recipe run in a subprocess, on the node that calls it.

    The run is skipped when its ``summary.json`` exists and continued with ``resume=true``
    when its ``checkpoint.pt`` does (decided here, when the run starts: a retried Ray task
    resumes what the lost one checkpointed). ``command[0]`` is replaced by this node's
    Python. A ``KeyboardInterrupt`` (Ctrl-C, ``ray.cancel``) is passed to the recipe as
    SIGINT (unblocked in the child: Ray workers block it), which checkpoints before it
    exits; on Linux the recipe also gets SIGINT when the calling process dies (a Ray
    worker killed with its driver), so no orphan keeps writing the run directory that a
    retry or a resubmission continues.

    Args:
        command (list of str): ``[python, "recipes/o2o.py", overrides...]``.
        run_dir (str): the run's ``output_dir``; gets ``stdout.txt`` and ``stderr.txt``.
        cwd (str): the repository root on this node.
        shared_token (tuple of str, optional): ``(path, text)`` that must be readable here
            (``--out`` is shared); else the run fails with the problem and the fix.

    Examples:
        >>> import sys, tempfile
        >>> with tempfile.TemporaryDirectory() as d:
        ...     outcome = run_recipe([sys.executable, "-c", "exit(3)"], d, d)
        >>> outcome["error"][:30]
        'exit 3, no summary.json; stder'
    """
    start, path = time.monotonic(), Path(run_dir)
    outcome = {"error": "", "seconds": 0.0, "machine": machine(), "provenance": provenance(cwd)}
    if shared_token is not None and not _token_matches(*shared_token):
        outcome["error"] = (
            f"error: {shared_token[0]} is not visible on node {platform.node()}: --out must "
            "be on storage that every node of the Ray cluster mounts at the same path"
        )
        return outcome
    path.mkdir(parents=True, exist_ok=True)
    if not (path / "summary.json").exists():  # else: finished, only the JSON is missing
        if (path / "checkpoint.pt").exists() and "resume=true" not in command:
            command = [*command, "resume=true"]
        # unbuffered: the recipe's stage lines reach stdout.txt as they are printed
        env = {**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}
        env["PYTHONUNBUFFERED"] = "1"
        with open(path / "stdout.txt", "w") as out, open(path / "stderr.txt", "w") as err:
            python = [sys.executable, *command[1:]]  # this node's interpreter
            proc = subprocess.Popen(
                python,
                cwd=cwd,
                env=env,
                stdout=out,
                stderr=err,
                preexec_fn=_recipe_preexec(),
            )
            try:
                code = _wait(proc)
            except KeyboardInterrupt:
                proc.send_signal(signal.SIGINT)
                proc.wait()
                raise
        if code != 0 or not (path / "summary.json").exists():
            tail = (path / "stderr.txt").read_text()[-2000:]
            outcome["error"] = f"exit {code}, no summary.json; stderr tail:\n{tail}"
    outcome["seconds"] = time.monotonic() - start
    return outcome


def _wait(proc: subprocess.Popen) -> int:
    """``proc.wait()`` that returns to Python every second: ``ray.cancel`` raises its
    ``KeyboardInterrupt`` in the worker only while Python code runs."""
    while True:
        try:
            return proc.wait(timeout=1.0)
        except subprocess.TimeoutExpired:
            pass


def _recipe_preexec() -> Callable[[], None]:
    """For ``Popen(preexec_fn=)``: SIGINT reaches the recipe and, on Linux, is sent to it
    when the thread that started it dies (``prctl(PR_SET_PDEATHSIG)``). The child gets
    SIGINT unblocked (a Ray worker blocks it, and a child inherits the mask) and not
    ignored: a driver started in the background of a non-interactive shell
    (``python -m benchmarks.learning ... &``) ignores SIGINT, and an ignored signal stays
    ignored through ``exec``."""
    prctl, parent = None, os.getpid()
    if sys.platform == "linux":
        import ctypes

        prctl = ctypes.CDLL(None, use_errno=True).prctl

    def preexec() -> None:
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # the recipe's Python then handles it
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
        if prctl is not None:
            prctl(1, signal.SIGINT)  # PR_SET_PDEATHSIG
            if os.getppid() != parent:  # the parent died before prctl
                os.kill(os.getpid(), signal.SIGINT)

    return preexec


def _token_matches(path: str, text: str) -> bool:
    try:
        return Path(path).read_text() == text
    except OSError:
        return False


def local_backend(suite: Suite, runs: list[Run]) -> Iterator[tuple[Run, Outcome]]:
    """``--jobs`` recipe subprocesses at a time on this machine, in the queue's order."""
    cwd = str(REPO)
    with ThreadPoolExecutor(max_workers=max(suite.args.jobs, 1)) as pool:
        futures = {
            pool.submit(run_recipe, suite.command(run), str(suite.run_dir(run)), cwd): run
            for run in runs
        }
        try:
            for future in as_completed(futures):
                yield futures[future], future.result()
        finally:  # interrupted: the running recipes got Ctrl-C too and checkpoint
            for future in futures:
                future.cancel()


def connect_ray(address: str | None) -> Any:
    """The ``ray`` module, connected: to ``address``, or (``None``) to the cluster that
    ``ray start`` runs on this machine (``RAY_ADDRESS`` or ``auto``), else to a new local
    runtime. A runtime the caller already started is used as it is."""
    import ray

    if not ray.is_initialized():
        try:
            ray.init(address=address, log_to_driver=False)
        except ConnectionError as error:
            raise SystemExit(
                f"error: --ray-address {address}: {error} Start a cluster (ray start --head) "
                "or leave --ray-address out to run on a local Ray runtime."
            ) from None
    return ray


def run_recipe_cancellably(*args: Any) -> Outcome:
    """:func:`run_recipe` in a Ray worker, with ``ray.cancel`` able to stop it.

    Ray cancels a running task with ``_thread.interrupt_main``, which does nothing where
    SIGINT is ignored, and Ray's processes inherit an ignored SIGINT from the process that
    started the runtime (a driver or ``ray start`` run in the background of a
    non-interactive shell). The worker's default handler is put back first (tasks run in
    its main thread).
    """
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGINT, signal.default_int_handler)
    return run_recipe(*args)


def ray_task(ray: Any, max_retries: int, num_gpus: float = 0.0) -> Any:
    """:func:`run_recipe_cancellably` as a Ray task of one CPU (and ``num_gpus`` GPUs: Ray
    then sets the task's ``CUDA_VISIBLE_DEVICES``, so ``device=cuda`` is its GPU), run
    again up to ``max_retries`` times when its worker or node is lost."""
    # by value: the workers need not find benchmarks/ on their sys.path
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    return ray.remote(num_cpus=1, num_gpus=num_gpus, max_retries=max_retries)(
        run_recipe_cancellably
    )


def ray_backend(suite: Suite, runs: list[Run]) -> Iterator[tuple[Run, Outcome]]:
    """One Ray task per run (one CPU each), submitted in the queue's order; yields the
    runs as their tasks finish. A task whose node is lost is retried ``--ray-retries``
    times and resumes from the run's checkpoint on the shared ``--out``."""
    ray = connect_ray(suite.args.ray_address)
    token = (str(suite.args.out / SHARED_TOKEN), uuid.uuid4().hex)
    Path(token[0]).parent.mkdir(parents=True, exist_ok=True)
    Path(token[0]).write_text(token[1])
    task = ray_task(ray, suite.args.ray_retries, suite.args.gpus_per_run)
    cwd = str(REPO)
    refs = {
        task.remote(suite.command(run), str(suite.run_dir(run)), cwd, token): run for run in runs
    }
    pending = list(refs)
    try:
        while pending:
            (ref,), pending = ray.wait(pending, num_returns=1)
            try:
                outcome = ray.get(ref)
            except ray.exceptions.RayError as error:  # e.g. out of retries after node losses
                outcome = {"error": f"Ray task failed: {error}", "seconds": 0.0, "machine": ""}
            yield refs[ref], outcome
    finally:
        if pending:  # interrupted: the recipes get SIGINT, checkpoint and exit
            for ref in pending:
                ray.cancel(ref)
            ray.wait(pending, num_returns=len(pending), timeout=120)


BACKENDS: dict[str, Callable[[Suite, list[Run]], Iterator[tuple[Run, Outcome]]]] = {
    "local": local_backend,
    "ray": ray_backend,
}
"""``--backend`` name -> the function that runs a queue and yields the finished runs."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The backend flags of ``python -m benchmarks.learning``."""
    parser.add_argument(
        "--backend", choices=list(BACKENDS), default="local", help="where the runs execute"
    )
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="local: processes")
    parser.add_argument(
        "--ray-address",
        help="ray: the cluster's address (default: the cluster `ray start` runs on this "
        "machine, else a local Ray runtime); --out must be shared by every node",
    )
    parser.add_argument(
        "--ray-retries", type=int, default=3, help="ray: retries of a task lost with its node"
    )
    parser.add_argument(
        "--gpus-per-run",
        type=float,
        default=0.0,
        help="ray: GPUs each run's task holds (1 with device=cuda: one GPU per run)",
    )


def check_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Rejects a Ray flag without ``--backend ray`` and ``--backend ray`` without Ray."""
    if args.backend != "ray" and args.ray_address is not None:
        parser.error("--ray-address needs --backend ray")
    if args.backend != "ray" and args.gpus_per_run:
        parser.error("--gpus-per-run needs --backend ray")
    if args.gpus_per_run < 0:
        parser.error(f"--gpus-per-run must be >= 0, got {args.gpus_per_run}")
    if args.backend == "ray" and importlib.util.find_spec("ray") is None:
        parser.error(f"--backend ray needs Ray, which is not installed: {INSTALL_RAY}")
