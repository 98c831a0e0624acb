"""Bad input to ``recipes/o2o.py`` ends with exit code 2 and one ``error:`` line.

Most cases compose the config in-process exactly as the command line does
(:func:`torchrl_dual.recipe.compose_checked`: Hydra composition, then
:func:`~torchrl_dual.recipe.validate_config`) and check the message; a handful run the
real command line to check the exit code, stderr and the absence of a traceback.
docs/recipe.md shows one example of each kind.
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from torchrl_dual.recipe import CONFIG_DIR, ConfigError, IQLLearner, O2ORun, compose_checked

REPO = Path(__file__).resolve().parents[2]
ENVS = (
    "adroit, antmaze, frozenlake, halfcheetah, hopper, pointmaze_large, pointmaze_medium, "
    "pointmaze_umaze, walker2d"
)

# (overrides, the message after "error: ")
CASES = [
    ("budget.online_frames=-5", "budget.online_frames=-5: must be an integer >= 0"),
    ("critic.expectile=1.5", "critic.expectile=1.5: must lie in (0, 1)"),
    ("env=mujoco", f"env=mujoco: unknown option; choose one of {ENVS}"),
    ("budget=tiny", "budget=tiny: unknown option; choose one of default, paper, smoke"),
    (
        "algo=nope",
        "algo=nope: unknown option; choose one of calql, dacer, diffql, diffql_la, diffuser, dual, "
        "edis, iql, iql_la, so2",
    ),
    ("algo=iql actor.temperature=-1", "actor.temperature=-1: must be a number >= 0"),
    ("algo=iql actor.hiden=3", "unknown key 'actor.hiden'; did you mean actor.hidden?"),
    (
        "algo=iql planner.horizon=4",
        "unknown key 'planner.horizon' in this config; it is a key of algo=diffuser or "
        "algo=dual or algo=edis: choose one, or leave the key out",
    ),
    (
        "budget.onlin_frames=3",
        "unknown key 'budget.onlin_frames'; did you mean budget.online_frames?",
    ),
    ("planner.hiden=3", "unknown key 'planner.hiden'; did you mean planner.hidden?"),
    (  # a key of another option of the group: name the option that has it
        "critic.bellman_loss=l2",
        "unknown key 'critic.bellman_loss' in this config; it is a key of critic=calql: "
        "choose it, or leave the key out",
    ),
    (  # a key that an algo file (a _global_ package) brings
        "algo=iql actor.weighting=sac",
        "unknown key 'actor.weighting' in this config; it is a key of algo=dual: choose it, "
        "or leave the key out",
    ),
    ("+foo=1", "unknown key 'foo'"),
    ("+seed=2", "+seed=2: seed exists already; write seed=2 to change it"),
    ("~planner.hidden", "missing key 'planner.hidden' in planner"),
    ("seed==3", "malformed override 'seed==3' (extraneous input '='); write key=value"),
    ("seed=0,1", "seed=0,1: a sweep needs --multirun (-m); write a list as key=[a,b]"),
    ("seed=-1", "seed=-1: must be an integer in [0, 4294967295]"),
    ("seed=1.5", "seed=1.5: must be an integer in [0, 4294967295]"),
    ("num_threads=0", "num_threads=0: must be an integer >= 1"),
    ("resume=maybe", "resume=maybe: must be true or false"),
    ("interrupt_at_frames=-1", "interrupt_at_frames=-1: must be null or an integer >= 0"),
    ("device=banana", "device=banana: not a torch device; use cpu, cuda or cuda:N"),
    ("budget.frames_per_batch=0", "budget.frames_per_batch=0: must be an integer >= 1"),
    ("budget.eval_episodes=0", "budget.eval_episodes=0: must be an integer >= 1"),
    ("budget.eval_every=0", "budget.eval_every=0: must be an integer >= 1"),
    ("budget.checkpoint_every=0", "budget.checkpoint_every=0: must be an integer >= 1"),
    ("budget.network_width=abc", "budget.network_width=abc: must be an integer >= 1"),
    (
        "budget.distill_updates=[10,10]",
        "budget.distill_updates=[10, 10]: must have 5 entries, one per halving round of "
        "planner.num_steps=32 -> 1",
    ),
    (
        "budget.distill_updates=[10,0,10,10,10]",
        "budget.distill_updates=[10, 0, 10, 10, 10]: must be a list of integers >= 1",
    ),
    ("planner.num_steps=24", "planner.num_steps=24: must be a power of 2 (1, 2, 4, 8, ...)"),
    (
        "planner.schedule=quadratic",
        "planner.schedule=quadratic: unknown option; choose one of cosine, linear",
    ),
    ("planner.action_condition_prob=1.5", "planner.action_condition_prob=1.5: must lie in [0, 1]"),
    (
        "env=frozenlake planner.horizon=100",
        "planner.horizon=100: must be < env.max_episode_steps=100 (a window holds "
        "horizon + 1 steps of one episode)",
    ),
    (
        "actor.latent=sample planner.schedule=linear",
        "actor.latent=sample: needs planner.schedule=cosine, which ends in pure noise (got linear)",
    ),
    (
        "actor.weighting=ranking",
        "actor.weighting=ranking: unknown option; choose one of advantage, sac, uniform",
    ),
    ("laplace.num_samples=-1", "laplace.num_samples=-1: must be an integer >= 0"),
    (
        "laplace.prior_precision=-1",
        "laplace.prior_precision=-1: must be 'evidence' or a number > 0",
    ),
    (
        "laplace.posterior_temperature=0",
        "laplace.posterior_temperature=0: must be 'data' or a number > 0",
    ),
    (
        "laplace.posterior_temperature=mean",
        "laplace.posterior_temperature=mean: must be 'data' or a number > 0",
    ),
    ("exploration.shift_weight=-0.1", "exploration.shift_weight=-0.1: must be a number >= 0"),
    (
        "exploration.transition_model=oracle",
        "exploration.transition_model=oracle: unknown option; choose one of frozen, shared",
    ),
    (
        "online.offline_fraction=1.0",
        "online.offline_fraction=1.0: must be a number in (0, 1) or 'joint'",
    ),
    (
        "augment.kind=edis",
        "augment.kind=edis: unknown option; choose one of none, planner",
    ),
    (
        "algo=edis augment.kind=none",
        "augment.kind=none: must be planner for algo=edis (EDIS is IQL plus planner "
        "augmentation; IQL alone is algo=iql)",
    ),
    (
        "algo=edis budget=smoke augment.every=500",
        "augment.every=500: exceeds the online phase's 200 updates (online.utd_ratio x "
        "budget.online_frames): no augmentation round would run; lower augment.every or use "
        "augment.kind=none",
    ),
    (
        "algo=edis planner.num_steps=1",
        "planner.num_steps=1: must be >= 2 with augment.kind=planner: the guidance shifts the "
        "means of the teacher's DDPM steps",
    ),
    ("critic.discount=0", "critic.discount=0: must lie in (0, 1]"),
    ("env.maze=tiny", "env.maze=tiny: unknown option; choose one of umaze, medium, large"),
    ("env=frozenlake env.epsilon=2", "env.epsilon=2: must lie in [0, 1]"),
    (
        "env.kind=mujoco",
        "env.kind=mujoco: unknown option; choose one of pointmaze, frozenlake, antmaze, locomotion, adroit",
    ),
    (
        "logger.backend=nope",
        "logger.backend=nope: unknown option; choose one of csv, tensorboard, wandb, mlflow, trackio",
    ),
    (
        "logger=wandb logger.mode=cloud",
        "logger.mode=cloud: unknown option; choose one of offline, online, disabled",
    ),
    (
        "logger.project=dual",
        "unknown key 'logger.project' in this config; it is a key of logger=wandb: choose it, "
        "or leave the key out",
    ),
    (
        "collector=mpi",
        "collector=mpi: unknown option; choose one of multi_async, multi_sync, ray, single",
    ),
    (
        "collector=multi_sync collector.num_workers=0",
        "collector.num_workers=0: must be an integer >= 1",
    ),
    (
        "+collector.num_workers=2",
        "collector.num_workers=2: collector=single collects in this process; choose "
        "collector=multi_sync or collector=multi_async for worker processes, collector=ray "
        "for Ray actors",
    ),
    (
        "collector=multi_sync collector.num_workers=3",
        "budget.frames_per_batch=500: collector=multi_sync splits each batch over "
        "collector.num_workers=3: use a multiple of it",
    ),
    (
        "collector.num_envs=3",
        "budget.frames_per_batch=500: collector.num_envs=3 envs collect equal shares of each "
        "batch: use a multiple of it",
    ),
    ("collector.num_envs=0", "collector.num_envs=0: must be an integer >= 1"),
    (
        "collector=multi_sync +collector.num_envs=4",
        "collector.num_envs=4: collector=multi_sync steps one env per worker; batched envs "
        "are collector=single's (collector=single collector.num_envs=N), or raise "
        "collector.num_workers",
    ),
    (
        "algo=calql collector.num_envs=4",
        "collector.num_envs=4: critic=calql labels one stream of online episodes with "
        "Monte-Carlo returns; use collector.num_envs=1 with it",
    ),
    (
        "algo=calql collector=multi_async",
        "collector=multi_async: critic=calql labels one stream of online episodes with "
        "Monte-Carlo returns; use collector=single with it",
    ),
    (
        "env=pointmaze_medium env.goal_cell=[0,0]",
        "env.goal_cell=[0, 0]: goal_cell [0, 0] is not an open cell of the medium maze (a "
        "[row, col] pair, row 0 at the top); open cells: [[1, 1], [1, 2], [1, 5], [1, 6], "
        "[2, 1], [2, 2], [2, 4], [2, 5], [2, 6], [3, 2], [3, 3], [3, 4], [4, 1], [4, 2], "
        "[4, 4], [4, 5], [4, 6], [5, 1], [5, 3], [5, 4], [5, 6], [6, 1], [6, 2], [6, 3], "
        "[6, 5], [6, 6]].",
    ),
    (
        "env.data_avoid_cells=[[1,1],[1,2],[1,3],[2,3],[3,1],[3,2],[3,3]]",
        "env.data_avoid_cells=[[1, 1], [1, 2], [1, 3], [2, 3], [3, 1], [3, 2], [3, 3]]: covers "
        "every open cell of the umaze maze, so the offline data would have nowhere to go; "
        "leave at least one open cell out",
    ),
    (
        "compile.compile_mode=ludicrous",
        "compile.compile_mode=ludicrous: unknown option; choose null or one of default, "
        "reduce-overhead, max-autotune, max-autotune-no-cudagraphs",
    ),
]


def compose(tmp_path: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR, [f"output_dir={tmp_path / 'run'}", "data_cache_dir=null", *overrides]
    )


def test_the_default_and_smoke_configs_are_valid(tmp_path):
    assert compose(tmp_path).budget.name == "default"
    assert compose(tmp_path, "budget=smoke", "env=frozenlake").planner.hidden == 64
    iql = compose(tmp_path, "algo=iql", "budget=smoke")
    assert (iql.actor.hidden, iql.online.utd_ratio, iql.critic.expectile) == (64, 0.5, 0.7)
    assert "planner" not in iql
    assert compose(tmp_path, "laplace.num_samples=0").laplace.num_samples == 0  # no-UQ ablation


@pytest.mark.parametrize(("overrides", "message"), CASES, ids=[c[0] for c in CASES])
def test_a_bad_input_fails_naming_the_key_the_value_and_what_is_allowed(
    overrides, message, tmp_path
):
    with pytest.raises(ConfigError) as err:
        compose(tmp_path, *overrides.split())
    assert str(err.value) == message


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_device_cuda_without_cuda_fails_before_anything_runs(tmp_path):
    with pytest.raises(
        ConfigError, match="^device=cuda: CUDA is not available here; use device=cpu$"
    ):
        compose(tmp_path, "device=cuda")


def test_an_output_dir_that_is_a_file_fails(tmp_path):
    path = tmp_path / "file"
    path.write_text("x")
    with pytest.raises(ConfigError) as err:
        compose_checked(CONFIG_DIR, [f"output_dir={path}"])
    assert str(err.value) == f"output_dir={path}: {path} is a file, not a directory"


def test_an_existing_checkpoint_without_resume_fails(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(
        ConfigError, match=r"^resume=false: .*checkpoint.pt exists: pass resume=true"
    ):
        compose(tmp_path)


def test_resume_with_a_logger_that_cannot_resume_fails(tmp_path, monkeypatch):
    from torchrl_dual.recipe.settings.loggers import LOGGERS

    as_if_installed = dataclasses.replace(LOGGERS["mlflow"], package=None)
    monkeypatch.setitem(LOGGERS, "mlflow", as_if_installed)
    with pytest.raises(ConfigError) as err:
        compose(tmp_path, "resume=true", "logger.backend=mlflow")
    assert str(err.value) == (
        "logger.backend=mlflow: cannot resume (resume=true); use one of csv, tensorboard, wandb"
    )


def test_a_batch_larger_than_the_offline_data_is_warned_about_at_once(tmp_path, capsys):
    """Sampled with replacement, such a batch works, slowly: one ``warning:`` line when the
    data are loaded, before any update."""
    from torchrl_dual.recipe.kits.build import make_offline_dataset

    overrides = ["env=frozenlake", "budget=smoke", "budget.dataset_transitions=200"]
    cfg = compose_checked(
        CONFIG_DIR,
        [*overrides, "budget.batch_size=100000", f"output_dir={tmp_path / 'run'}",
         f"data_cache_dir={tmp_path / 'data'}"],
    )  # fmt: skip
    assert len(make_offline_dataset(cfg)) == 200
    assert capsys.readouterr().err.splitlines() == [
        "warning: budget.batch_size=100000 exceeds the 200 transitions of the offline data: "
        "drawn with replacement, a batch holds each about 500 times and every update pays for "
        "all 100000; lower it to at most 200"
    ]
    cfg.budget.batch_size = 200
    make_offline_dataset(cfg)
    assert capsys.readouterr().err == ""


# ----------------------------------------------------------------------------- command line
def recipe(*args: str, cwd: Path = REPO, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "recipes/o2o.py", *args],
        cwd=cwd,
        env={**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0", **env},
        capture_output=True,
        text=True,
        timeout=300,
    )


# one composition error and one validation error through the real command line; the
# others of CASES go through the same check in-process above
@pytest.mark.parametrize("override", ["budget.onlin_frames=3", "output_dir"])
def test_the_command_line_exits_2_with_one_error_line_and_no_traceback(override, tmp_path):
    if override == "output_dir":  # an existing file: Hydra must not get to create it
        (tmp_path / "file").write_text("x")
        override = f"output_dir={tmp_path / 'file'}"
    proc = recipe(override, f"hydra.run.dir={tmp_path / 'hydra'}")
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert proc.stderr.strip().splitlines() == [f"error: {self_message(override, tmp_path)}"]
    assert "Traceback" not in proc.stdout + proc.stderr
    assert not (tmp_path / "hydra").exists()  # stopped before Hydra's run directory


def self_message(override: str, tmp_path: Path) -> str:
    if override.startswith("output_dir="):
        path = override.split("=", 1)[1]
        return f"{override}: {path} is a file, not a directory"
    return dict(CASES)[override]


def test_an_output_dir_that_cannot_be_created_ends_in_one_error_line(tmp_path):
    """``/proc`` takes no new folders (not even for root): one ``error:`` line, exit 2, no
    traceback, instead of Hydra's ``FileNotFoundError``; and nothing left behind."""
    proc = recipe("output_dir=/proc/x/run", f"hydra.run.dir={tmp_path / 'hydra'}")
    assert proc.returncode == 2, proc.stderr[-3000:]
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("error: output_dir=/proc/x/run: cannot be created or written in /proc")
    assert line.endswith("choose a directory you can write to")
    assert "Traceback" not in proc.stdout + proc.stderr
    with pytest.raises(ConfigError, match="cannot be created or written"):
        compose_checked(CONFIG_DIR, ["output_dir=/proc/x/run"])
    assert not list(tmp_path.iterdir())


def test_resume_true_without_a_checkpoint_says_it_starts_a_new_run(tmp_path, capsys):
    cfg = compose_checked(
        CONFIG_DIR,
        ["algo=iql", "budget=smoke", "resume=true", f"output_dir={tmp_path / 'run'}",
         f"data_cache_dir={tmp_path / 'data'}", "progress=false"],
    )  # fmt: skip
    O2ORun(cfg, IQLLearner)
    assert f"[iql] resume=true: no checkpoint in {tmp_path / 'run'}; starting a new run" in (
        capsys.readouterr().out.splitlines()
    )


def test_debug_true_adds_the_traceback_and_still_exits_2(tmp_path):
    proc = recipe("critic.expectile=1.5", "debug=true", f"output_dir={tmp_path / 'run'}")
    assert proc.returncode == 2
    assert "Traceback" in proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == "error: critic.expectile=1.5: must lie in (0, 1)"


def test_cfg_job_still_prints_the_config_and_a_multirun_job_reports_its_error(tmp_path):
    proc = recipe("--cfg", "job", "budget=smoke")
    assert proc.returncode == 0 and "network_width: 64" in proc.stdout
    proc = recipe("-m", "critic.expectile=1.5", f"hydra.sweep.dir={tmp_path / 'sweep'}")
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert "error: critic.expectile=1.5: must lie in (0, 1)" in proc.stderr.splitlines()
    assert "Traceback" not in proc.stderr
