"""``python -m benchmarks.learning --backend ray`` on a local Ray runtime started here: the same
runs and the same results table as ``--backend local``, and a task lost with its worker is
retried and resumes from the run's checkpoint."""

from __future__ import annotations

import doctest
import json
import signal
import sys
import textwrap
import time
from pathlib import Path

import pytest

from benchmarks.learning import backends as learning_backends
from benchmarks.learning import suite as learning

REPO = Path(__file__).resolve().parents[1]

# budget=smoke shrunk further, as in test_learning_suite.py's end-to-end suite test
pytestmark = [
    pytest.mark.usefixtures("ray_exclusive"),
    pytest.mark.long_running(seconds=40),
]  # starts first under xdist; one Ray module at a time
FAST = (
    *("budget.offline_updates=10", "budget.online_frames=100", "budget.frames_per_batch=50"),
    *("budget.eval_every=50", "budget.eval_episodes=1", "budget.checkpoint_every=50"),
    # the TanhNormal actor: at this budget its one-episode scores move between evaluations
    # (the Gaussian default's stay equal), which the non-triviality check below needs
    "actor.distribution=tanh_normal",
)
GRID = ("--budget", "smoke", "--cells", "frozenlake8x8_slip", "--variants", "iql")


@pytest.fixture(scope="module")
def ray_runtime(request):
    ray = pytest.importorskip(
        "ray",
        reason="ray is not installed (pip install 'torchrl-dual[ray]'; "
        "Ray publishes no wheel for some platforms)",
    )
    # started as from a driver that ignores SIGINT (a background job of a non-interactive
    # shell, which is how CI may run pytest): Ray's processes inherit it, and a cancelled
    # task must still stop its recipe
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    finally:
        signal.signal(signal.SIGINT, previous)
    request.addfinalizer(ray.shutdown)
    return ray


def suite_flags(root: Path, *flags: str) -> list[str]:
    """``python -m benchmarks.learning`` flags writing everything under ``root``."""
    return [
        *flags,
        *("--out", str(root / "out"), "--results", str(root / "results")),
        *("--docs", str(root / "results.md"), "--figures", str(root / "figures")),
    ]


def table_without_times(docs: Path) -> list[list[str]]:
    """The rows of the generated section's tables without the wall and CPU minutes
    (which differ from one execution to the next)."""
    rows, drop = [], set()
    for line in docs.read_text().splitlines():
        if not line.startswith("| "):
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        if cells[0] == "variant":
            drop = {i for i, c in enumerate(cells) if c.endswith(" min")}
        rows.append([c for i, c in enumerate(cells) if i not in drop])
    return rows


def test_ray_backend_writes_the_runs_and_table_of_the_local_backend(ray_runtime, tmp_path, capsys):
    local, ray = tmp_path / "local", tmp_path / "ray"
    seeds = ("--seeds", "0")  # one run per backend: the test's time is two recipe runs
    assert learning.main(suite_flags(local, *GRID, *seeds, "--jobs", "2", *FAST)) == 0
    assert learning.main(suite_flags(ray, *GRID, *seeds, "--backend", "ray", *FAST)) == 0
    printed = capsys.readouterr().out
    assert printed.count("1 runs in the grid, 0 already done, 1 to run") == 2
    names = sorted(p.relative_to(local / "results") for p in local.glob("results/**/*.json"))
    assert [str(n) for n in names] == ["smoke/frozenlake8x8_slip/iql/seed0.json"]
    assert sorted(p.relative_to(ray / "results") for p in ray.glob("results/**/*.json")) == names
    timing = {"offline_seconds", "online_seconds", "wall_seconds", "stage_seconds", "date"}
    timing |= {"offline_cpu_seconds", "cpu_seconds", "stage_cpu_seconds", "provenance"}
    for name in names:
        a, b = (json.loads((root / "results" / name).read_text()) for root in (local, ray))
        # where it ran, read on the Ray worker as on this process: the same host and commit
        assert {k: v for k, v in a["provenance"].items() if k != "date"} == {
            k: v for k, v in b["provenance"].items() if k != "date"
        }
        # same seed, one thread, same machine: every score is bit-equal
        assert {k: v for k, v in a.items() if k not in timing} == {
            k: v for k, v in b.items() if k not in timing
        }
        assert len(a["history"]) == 3 and b["wall_seconds"] > 0
        # not a trivial equality: the scores without the shift move over the run
        assert len({h["normalized_score_unshifted"] for h in a["history"]}) == 3
    assert table_without_times(local / "results.md") == table_without_times(ray / "results.md")
    assert any(
        row[0] == "`iql`" and row[1] == "1" for row in table_without_times(ray / "results.md")
    )
    # resubmitting the grid skips the finished runs: no task is submitted
    assert learning.main(suite_flags(ray, *GRID, *seeds, "--backend", "ray", *FAST)) == 0
    assert "1 runs in the grid, 1 already done, 0 to run" in capsys.readouterr().out


# A stand-in recipe: the first attempt writes a checkpoint and kills its parent (the Ray
# worker, as a lost node would), then would sleep as an orphan (it gets SIGINT, or Ray
# kills it); the next attempt must be started with resume=true and finishes.
FAKE_RECIPE = textwrap.dedent(
    """
    import json, os, signal, sys, time
    from pathlib import Path
    run = Path(sys.argv[1])
    with open(run.parent / "attempts.txt", "a") as log:
        log.write(" ".join(sys.argv[2:]) + "\\n")
    if not (run / "checkpoint.pt").exists():
        (run / "checkpoint.pt").write_bytes(b"state")
        (run.parent / "first.pid").write_text(str(os.getpid()))
        def stopped(*_):  # the recipe's SIGINT: checkpoint and exit
            with open(run.parent / "attempts.txt", "a") as log:
                log.write("SIGINT after the worker died\\n")
            sys.exit(130)
        signal.signal(signal.SIGINT, stopped)
        os.kill(os.getppid(), signal.SIGKILL)
        time.sleep(20)
        sys.exit(1)
    assert "resume=true" in sys.argv
    history = [{"label": "offline", "frames": 0, "normalized_score": 1.0, "return": 0.0},
               {"label": "online", "frames": 50, "normalized_score": 3.0, "return": 0.0}]
    summary = {"seed": 0, "budget": "smoke", "algo": "iql", "env": "frozenlake",
               "history": history, "offline_seconds": 1.0, "wall_seconds": 2.0}
    (run / "summary.json").write_text(json.dumps(summary))
    """
)


def running(pid: int) -> bool:
    """Whether process ``pid`` exists and is not a zombie (Linux ``/proc``)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] not in "ZX"
    except FileNotFoundError:
        return False


def test_a_task_lost_with_its_worker_is_retried_and_resumes_from_the_checkpoint(
    ray_runtime, tmp_path, monkeypatch, capsys
):
    def fake_command(self, run):
        return [sys.executable, "-c", FAKE_RECIPE, str(self.run_dir(run)), f"seed={run.seed}"]

    monkeypatch.setattr(learning.Suite, "command", fake_command)
    flags = suite_flags(tmp_path, *GRID, "--seeds", "0", "--backend", "ray", "--ray-retries", "1")
    assert learning.main(flags) == 0, capsys.readouterr()
    run_dir = tmp_path / "out" / "smoke" / "frozenlake8x8_slip" / "iql" / "seed0"
    attempts = (run_dir.parent / "attempts.txt").read_text().splitlines()
    assert [a for a in attempts if not a.startswith("SIGINT")] == ["seed=0", "seed=0 resume=true"]
    # the first attempt is no orphan writing the run dir: SIGINT (if it wins the race)
    # or Ray's clean-up of the dead worker's processes has stopped it
    first, deadline = int((run_dir.parent / "first.pid").read_text()), time.monotonic() + 10
    while running(first):
        assert time.monotonic() < deadline, "the lost attempt's recipe still runs"
        time.sleep(0.2)
    result = json.loads(
        (tmp_path / "results" / "smoke/frozenlake8x8_slip/iql/seed0.json").read_text()
    )
    assert (result["offline_score"], result["final_score"]) == (1.0, 3.0)
    # out of retries: the run fails with Ray's reason and the suite exits 1
    (run_dir / "summary.json").unlink()
    (run_dir / "checkpoint.pt").unlink()
    (tmp_path / "results" / "smoke/frozenlake8x8_slip/iql/seed0.json").unlink()
    flags[flags.index("--ray-retries") + 1] = "0"
    assert learning.main(flags) == 1
    printed = capsys.readouterr()
    assert "FAILED frozenlake8x8_slip/iql/seed0: Ray task failed:" in printed.out
    assert "1 runs failed: frozenlake8x8_slip/iql/seed0" in printed.err


def test_a_cancelled_task_passes_sigint_to_the_recipe(ray_runtime, tmp_path):
    # Ctrl-C on the driver cancels the tasks; the recipe must get SIGINT to checkpoint
    log = tmp_path / "log.txt"
    recipe = textwrap.dedent(
        f"""
        import sys, time
        try:  # as the recipe: Python's own SIGINT handler, KeyboardInterrupt
            open({str(log)!r}, "a").write("up\\n")
            time.sleep(300)
        except KeyboardInterrupt:
            open({str(log)!r}, "a").write("SIGINT\\n")
            sys.exit(130)
        """
    )
    task = learning_backends.ray_task(ray_runtime, max_retries=0)
    ref = task.remote([sys.executable, "-c", recipe], str(tmp_path / "run"), str(tmp_path))
    # a fresh Ray worker (and the recipe it starts) can take long to come up on two busy
    # cores (under xdist next to a compiling test): the cancel must reach a running recipe
    start = time.monotonic()
    while not log.exists():
        assert time.monotonic() < start + 180, "the task's recipe did not start in 180 s"
        time.sleep(0.2)
    ray_runtime.cancel(ref)
    ready, _ = ray_runtime.wait([ref], timeout=60)
    assert ready, f"the cancelled task did not return in 60 s (log: {log.read_text()!r})"
    assert log.read_text() == "up\nSIGINT\n"
    with pytest.raises(ray_runtime.exceptions.TaskCancelledError):
        ray_runtime.get(ref)


def test_a_run_fails_with_the_fix_when_out_is_not_shared_with_its_node(tmp_path):
    token = (str(tmp_path / "elsewhere" / learning_backends.SHARED_TOKEN), "abc")
    outcome = learning_backends.run_recipe(
        [sys.executable, "-c", "pass"], str(tmp_path / "run"), str(REPO), token
    )
    assert outcome["error"].startswith(f"error: {token[0]} is not visible on node ")
    assert "--out must be on storage that every node" in outcome["error"]
    assert not (tmp_path / "run").exists()  # nothing ran
    Path(token[0]).parent.mkdir()
    Path(token[0]).write_text("abc")
    assert learning_backends.run_recipe(
        [sys.executable, "-c", "pass"], str(tmp_path / "run"), str(REPO), token
    )["error"].startswith("exit 0, no summary.json")


def test_ray_flags_need_the_ray_backend(capsys, monkeypatch):
    with pytest.raises(SystemExit) as stop:
        learning.main(["--ray-address", "auto", "--dry-run"])
    assert stop.value.code == 2
    assert "error: --ray-address needs --backend ray" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        learning.main(["--gpus-per-run", "1", "--dry-run"])
    assert "error: --gpus-per-run needs --backend ray" in capsys.readouterr().err
    # where Ray does not install, --backend ray names the extra to install
    monkeypatch.setattr(
        learning_backends.importlib.util, "find_spec", lambda name: None if name == "ray" else 1
    )
    with pytest.raises(SystemExit):
        learning.main(["--backend", "ray", "--dry-run"])
    assert "--backend ray needs Ray, which is not installed: pip install 'torchrl-dual[ray]'" in (
        capsys.readouterr().err
    )


def test_backend_docstring_examples_run():
    failures, tried = doctest.testmod(learning_backends, optionflags=doctest.ELLIPSIS)
    assert (failures, tried >= 3) == (0, True)


def test_a_run_s_task_holds_the_gpus_asked_for(ray_runtime):
    """``--gpus-per-run 1``: each run's task holds one GPU (Ray then hands it its own
    ``CUDA_VISIBLE_DEVICES``); by default none."""
    assert learning_backends.ray_task(ray_runtime, 0)._default_options["num_gpus"] == 0.0
    task = learning_backends.ray_task(ray_runtime, 0, num_gpus=1.0)
    assert task._default_options["num_gpus"] == 1.0 and task._default_options["num_cpus"] == 1
