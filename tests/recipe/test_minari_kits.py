"""The Minari env kits (antmaze, locomotion, adroit) on data sets written here under the
published ids: loading, dict-observation flattening, episode boundaries, terminated vs
truncated, reward modification, state normalization, reference scores, the data set's own
online and evaluation envs, the family presets, and the errors for missing data."""

from __future__ import annotations

import math
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("h5py", reason="Minari's storage needs h5py: pip install 'minari[hdf5]'")
minari = pytest.importorskip("minari")

from recipe_runner import compose_smoke, failed, run_recipe, standin_minari_datasets  # noqa: E402

from torchrl_dual.data.minari_standins import (  # noqa: E402
    UMAZE_EVAL_MAP,
    UMAZE_MAP,
)
from torchrl_dual.recipe import ConfigError, UserError, run  # noqa: E402
from torchrl_dual.recipe.kits import build as env_kits  # noqa: E402
from torchrl_dual.recipe.kits.minari_families import (  # noqa: E402
    OBSERVATION_STD_EPS,
    check_observation_layout,
    minari_gym_env,
)

ANTMAZE_ID, HOPPER_ID, PEN_ID = (
    "D4RL/antmaze/umaze-v1",
    "mujoco/hopper/medium-v0",
    "D4RL/pen/cloned-v2",
)
FAST = [
    "budget.offline_updates=10",
    "online.utd_ratio=0.2",
    "budget.online_frames=60",
    "budget.frames_per_batch=30",
    "budget.eval_every=60",
    "budget.checkpoint_every=60",
    "budget.eval_episodes=2",
    "budget.laplace_refit_every=10",
    "env.max_episode_steps=25",
]


@pytest.fixture(scope="module")
def minari_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("minari_datasets")
    with standin_minari_datasets(
        root, {ANTMAZE_ID: (4, 40), HOPPER_ID: (6, 60), PEN_ID: (3, 40)}
    ) as path:
        yield path


def compose(tmp_path: Path, *overrides: str):
    return compose_smoke(tmp_path, *overrides)


def raw_episodes(dataset_id: str):
    return list(minari.load_dataset(dataset_id).iterate_episodes())


# ----------------------------------------------------------------------------- data
def test_antmaze_data_is_flattened_normalized_and_shifted(minari_path, tmp_path):
    data = env_kits.make_offline_dataset(compose(tmp_path, "env=antmaze", "env.protocol=minari"))
    episodes = raw_episodes(ANTMAZE_ID)
    keys = ("achieved_goal", "observation", "desired_goal")
    raw_obs = np.concatenate(
        [np.concatenate([ep.observations[k][:-1] for k in keys], -1) for ep in episodes]
    )
    assert data.metadata["observation_keys"] == list(keys)
    mean, std = raw_obs.mean(0), raw_obs.std(0) + OBSERVATION_STD_EPS
    expected = (raw_obs - mean) / std
    assert torch.allclose(
        data.transitions["observation"], torch.as_tensor(expected).float(), atol=1e-4
    )
    raw_rewards = np.concatenate([ep.rewards for ep in episodes])
    assert torch.equal(
        data.transitions["next", "reward"].squeeze(-1),
        torch.as_tensor(raw_rewards, dtype=torch.float32) - 1.0,
    )
    # episode boundaries: one id per episode, truncated only at each episode's last step
    ids = data.transitions["episode"]
    assert ids.unique().numel() == len(episodes) == 4
    truncated = data.transitions["next", "truncated"].squeeze(-1)
    assert torch.equal(
        truncated, torch.as_tensor(np.concatenate([ep.truncations for ep in episodes]))
    )
    assert int(truncated.sum()) == 4 and not data.transitions["next", "terminated"].any()
    # the next observation of step t is the observation of step t + 1 within an episode
    same_episode = ids[1:] == ids[:-1]
    assert torch.equal(
        data.transitions["next", "observation"][:-1][same_episode],
        data.transitions["observation"][1:][same_episode],
    )


def test_locomotion_keeps_terminations_and_scales_rewards_by_the_return_range(
    minari_path, tmp_path
):
    cfg = compose(tmp_path, "env=hopper", "env.normalize_observations=false", "env.protocol=minari")
    data = env_kits.make_offline_dataset(cfg)
    episodes = raw_episodes(HOPPER_ID)
    returns = np.array([ep.rewards.sum() for ep in episodes])
    scale = 1000 / (returns.max() - returns.min())  # Hopper-v5's time limit / return range
    raw_rewards = np.concatenate([ep.rewards for ep in episodes])
    assert data.metadata["reward_scale"] == pytest.approx(scale)
    assert np.allclose(
        data.transitions["next", "reward"].squeeze(-1).numpy(), raw_rewards * scale, rtol=1e-5
    )
    terminated = np.concatenate([ep.terminations for ep in episodes])
    assert np.array_equal(data.transitions["next", "terminated"].squeeze(-1).numpy(), terminated)
    raw_obs = np.concatenate([ep.observations[:-1] for ep in episodes])
    assert np.allclose(
        data.transitions["observation"].numpy(), raw_obs, atol=1e-6
    )  # not normalized
    assert data.reference_min is None  # the data set has no references


# ----------------------------------------------------------------------------- envs
def test_online_env_is_the_data_sets_env_behind_the_same_observation_map(minari_path, tmp_path):
    cfg = compose(tmp_path, "env=antmaze", "env.max_episode_steps=10", "env.protocol=minari")
    data = env_kits.make_offline_dataset(cfg)
    env = env_kits.make_train_env(cfg, data)
    rollout = env.rollout(10)
    assert rollout["observation"].shape == (10, 31)
    assert torch.all(rollout["next", "reward"] == -1.0)  # far from the goal: r = 0, then r - 1
    assert rollout["next", "truncated"][-1].item()
    train = minari_gym_env(cfg, data, eval_env=False, shifted=False)
    evaluation = minari_gym_env(cfg, data, eval_env=True, shifted=False)
    assert train.unwrapped.maze.maze_map == UMAZE_MAP
    assert evaluation.unwrapped.maze.maze_map == UMAZE_EVAL_MAP
    assert np.array_equal(train.loc, np.asarray(data.metadata["observation_loc"], np.float32))
    obs, _ = train.reset(seed=3)
    raw, _ = train.env.reset(seed=3)
    assert np.allclose(obs, (train.flatten(raw) - train.loc) / train.scale)


def test_a_worker_s_env_is_built_from_the_data_set_s_description_not_its_data(
    minari_path, tmp_path, monkeypatch
):
    """``collector.num_workers`` processes each build their env from a ``TrainEnvFactory``:
    it carries the data set without its transitions (a few kB through the pickle), and
    the env it builds normalizes and scales like the run's, without reading the data set
    again."""
    import pickle

    from torchrl_dual.recipe.kits import minari_families as minari_kits

    cfg = compose(tmp_path, "env=hopper", "env.max_episode_steps=10")
    data = env_kits.make_offline_dataset(cfg)
    factory = pickle.loads(pickle.dumps(env_kits.TrainEnvFactory(cfg, data)))
    assert len(pickle.dumps(env_kits.TrainEnvFactory(cfg, data))) < 20_000 < len(pickle.dumps(data))

    def no_reading(*args, **kwargs):
        raise AssertionError("the worker read the data set again")

    monkeypatch.setattr(minari_kits, "load_minari_dataset", no_reading)
    worker_env, run_env = factory(), env_kits.make_train_env(cfg, data)
    worker_env.set_seed(5)
    run_env.set_seed(5)
    assert torch.equal(worker_env.reset()["observation"], run_env.reset()["observation"])
    assert factory.data.metadata == data.metadata


def test_a_changed_observation_layout_is_refused():
    import gymnasium as gym

    box = gym.spaces.Box(-1, 1, (27,))
    data_space = gym.spaces.Dict({"observation": box, "desired_goal": gym.spaces.Box(-1, 1, (2,))})
    env_space = gym.spaces.Dict({"observation": gym.spaces.Box(-1, 1, (29,)), "desired_goal": box})
    with pytest.raises(UserError, match="differ from its env"):
        check_observation_layout(data_space, env_space, ANTMAZE_ID)


# ----------------------------------------------------------------------------- runs
def test_antmaze_runs_dual_end_to_end(minari_path, tmp_path):
    result = run(compose(tmp_path, "env=antmaze", "num_threads=1", "planner.horizon=4", *FAST))
    labels = [h["label"] for h in result.history]
    assert labels == ["offline", "online"]
    for h in result.history:  # D4RL's task: the return is 1 on success, 0 otherwise
        assert 0.0 <= h["return"] <= 1.0
        assert h["normalized_score"] == pytest.approx(100 * h["return"])
    assert (tmp_path / "run" / "summary.json").is_file()


def test_antmaze_runs_under_minari_s_protocol_with_the_data_set_s_references(minari_path, tmp_path):
    overrides = ("env=antmaze", "env.protocol=minari", "algo=iql", "num_threads=1", *FAST)
    result = run(compose(tmp_path, *overrides))
    for h in result.history:
        assert h["normalized_score"] == pytest.approx(100 * h["return"] / 400.0)


def test_hopper_without_references_says_so(minari_path, tmp_path, capsys):
    overrides = ("env=hopper", "env.protocol=minari", "algo=iql", "num_threads=1", *FAST)
    result = run(compose(tmp_path, *overrides))
    assert all(math.isnan(h["normalized_score"]) for h in result.history)
    out = capsys.readouterr().out
    assert "normalized score n/a (the data set has no reference returns" in out


@pytest.mark.parametrize(
    "protocol, references",
    [("d4rl", (96.262799, 3076.8331017826877)), ("minari", (96.26, 3076.83))],
)
def test_pen_scores_are_normalized_with_the_protocol_s_references(
    minari_path, tmp_path, protocol, references
):
    """d4rl: D4RL's ``pen-human-v0`` numbers; minari: the data set's (the stand-in's)."""
    overrides = ("env=adroit", f"env.protocol={protocol}", "algo=iql", "num_threads=1", *FAST)
    result = run(compose(tmp_path, *overrides))
    low, high = references
    for h in result.history:
        assert h["normalized_score"] == pytest.approx(100 * (h["return"] - low) / (high - low))


def test_reference_returns_override_the_data_sets(minari_path, tmp_path):
    data = env_kits.make_offline_dataset(
        compose(tmp_path, "env=hopper", "env.reference_returns=[-20.0,3234.0]")
    )
    assert data.normalized_score(-20.0) == 0.0 and data.normalized_score(3234.0) == 100.0


# ----------------------------------------------------------------------------- config
@pytest.mark.parametrize(
    "env, expectile, temperature",
    [
        ("antmaze", 0.9, 10.0),
        ("hopper", 0.7, 3.0),
        ("adroit", 0.8, 3.0),
        ("pointmaze_umaze", 0.7, 3.0),
    ],
)
def test_the_family_presets_set_the_critic_and_actor(
    minari_path, tmp_path, env, expectile, temperature
):
    cfg = compose(tmp_path, f"env={env}")
    assert (cfg.critic.expectile, cfg.actor.temperature) == (expectile, temperature)
    cfg = compose(tmp_path, f"env={env}", "critic.expectile=0.6", "actor.temperature=1.0")
    assert (cfg.critic.expectile, cfg.actor.temperature) == (0.6, 1.0)


def test_a_missing_data_set_names_the_download_command(minari_path, tmp_path):
    with pytest.raises(ConfigError) as info:
        compose(tmp_path, "env=antmaze", "env.dataset=large-play")
    message = str(info.value)
    assert "minari download D4RL/antmaze/large-play-v1" in message
    assert str(minari_path / "D4RL" / "antmaze" / "large-play-v1") in message
    with pytest.raises(ConfigError, match="minari download D4RL/door/human-v2"):
        compose(tmp_path, "env=adroit", "env.task=door", "env.dataset=human")


def test_without_minari_the_error_names_the_extra(minari_path, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "minari.storage", None)
    with pytest.raises(ConfigError, match=r"pip install 'torchrl-dual\[minari\]'"):
        compose(tmp_path, "env=hopper")


def test_the_command_line_stops_with_one_error_line(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "empty"))
    line = failed(run_recipe(tmp_path / "out", tmp_path / "cache", "env=antmaze"))
    assert "minari download D4RL/antmaze/umaze-v1" in line


def test_a_datasets_path_that_is_a_file_ends_in_one_error_line(tmp_path, monkeypatch):
    path = tmp_path / "file"
    path.write_text("x")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(path))
    line = failed(run_recipe(tmp_path / "out", tmp_path / "cache", "env=antmaze"))
    assert line == (
        f"error: MINARI_DATASETS_PATH={path}: not a directory Minari can use (File exists: "
        f"{path}); point it at a directory, or unset it to use ~/.minari/datasets"
    )


def test_a_damaged_metadata_file_is_named_with_the_download_command(
    minari_path, tmp_path, monkeypatch
):
    datasets = tmp_path / "datasets"
    shutil.copytree(minari_path, datasets)
    metadata = datasets / "D4RL" / "antmaze" / "umaze-v1" / "data" / "metadata.json"
    metadata.write_text("{broken")
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(datasets))
    line = failed(run_recipe(tmp_path / "out", tmp_path / "cache", "env=antmaze"))
    assert line.startswith(
        "error: env.dataset=umaze: the Minari data set D4RL/antmaze/umaze-v1 is damaged: "
        f"{metadata} cannot be read ("
    )
    assert line.endswith("download it again with: minari download --force D4RL/antmaze/umaze-v1")


def test_ids_of_the_published_families():
    from omegaconf import OmegaConf

    from torchrl_dual.recipe.kits.minari_families import FAMILIES

    def dataset_id(kind: str, **env) -> str:
        return FAMILIES[kind].dataset_id(OmegaConf.create(env))

    assert dataset_id("antmaze", dataset="umaze", dataset_version="v1") == ANTMAZE_ID
    assert (
        dataset_id("locomotion", task="hopper", dataset="medium", dataset_version="v0") == HOPPER_ID
    )
    assert dataset_id("adroit", task="pen", dataset="cloned", dataset_version="v2") == PEN_ID


def test_an_odrl_shift_reaches_the_online_and_evaluation_envs_not_the_data(minari_path, tmp_path):
    plain_cfg = compose(tmp_path, "env=hopper")
    cfg = compose(tmp_path, "env=hopper", "env.shift=gravity")
    data = env_kits.make_offline_dataset(cfg)
    plain = env_kits.make_offline_dataset(plain_cfg)
    assert (data.transitions == plain.transitions).all()
    gravity = minari_gym_env(
        plain_cfg, plain, eval_env=True, shifted=True
    ).unwrapped.model.opt.gravity
    for eval_env in (False, True):
        shifted = minari_gym_env(
            cfg, data, eval_env=eval_env, shifted=True
        ).unwrapped.model.opt.gravity
        assert np.allclose(shifted, 2.0 * gravity)
    online = env_kits.make_train_env(cfg, data)
    assert np.allclose(online.base_env._env.unwrapped.model.opt.gravity, 2.0 * gravity)
