"""load_minari_dataset: a Minari data set written locally loads back exactly."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch

pytest.importorskip(
    "h5py", reason="Minari's default storage needs h5py: pip install 'minari[hdf5]'"
)
minari = pytest.importorskip("minari")
from minari.data_collector import EpisodeBuffer  # noqa: E402

from torchrl_dual.data import default_observation_keys, load_minari_dataset  # noqa: E402
from torchrl_dual.envs import make_pointmaze_gym_env  # noqa: E402


@pytest.fixture(autouse=True)
def datasets_path(tmp_path, monkeypatch):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    return tmp_path


def _collect(env, num_episodes: int):
    """Steps ``env`` with random actions; returns Minari buffers and the raw episodes."""
    buffers, episodes = [], []
    env.action_space.seed(0)
    for ep in range(num_episodes):
        obs, _ = env.reset(seed=ep)
        steps = {"obs": [obs], "act": [], "rew": [], "term": [], "trunc": []}
        done = False
        while not done:
            action = env.action_space.sample()
            obs, reward, terminated, truncated, _ = env.step(action)
            for key, value in zip(steps, (obs, action, reward, terminated, truncated), strict=True):
                steps[key].append(value)
            done = terminated or truncated
        if isinstance(obs, dict):
            observations = {k: np.stack([o[k] for o in steps["obs"]]) for k in obs}
        else:
            observations = np.stack(steps["obs"])
        buffers.append(
            EpisodeBuffer(
                id=ep,
                observations=observations,
                actions=np.stack(steps["act"]),
                rewards=np.array(steps["rew"]),
                terminations=np.array(steps["term"]),
                truncations=np.array(steps["trunc"]),
                infos={},
            )
        )
        episodes.append(steps)
    return buffers, episodes


def _create(dataset_id, buffers, env, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        minari.create_dataset_from_buffers(
            dataset_id, buffers, env=env, algorithm_name="random", **kwargs
        )


def test_pointmaze_dataset_loads_exactly_what_was_written():
    env = make_pointmaze_gym_env("umaze", max_episode_steps=15)
    buffers, episodes = _collect(env, 3)
    _create("test/pointmaze/tiny-v0", buffers, env, ref_min_score=1.0, ref_max_score=5.0)

    data = load_minari_dataset("test/pointmaze/tiny-v0")
    td = data.transitions
    flat = [
        np.concatenate(
            [np.concatenate([o["observation"], o["desired_goal"]])[None] for o in ep["obs"]]
        )
        for ep in episodes
    ]
    expected_obs = np.concatenate([f[:-1] for f in flat])
    expected_next = np.concatenate([f[1:] for f in flat])
    np.testing.assert_array_equal(td["observation"].numpy(), expected_obs.astype(np.float32))
    np.testing.assert_array_equal(
        td["next", "observation"].numpy(), expected_next.astype(np.float32)
    )
    np.testing.assert_array_equal(
        td["action"].numpy(), np.concatenate([e["act"] for e in episodes])
    )
    np.testing.assert_array_equal(
        td["next", "reward"].squeeze(-1).numpy(),
        np.concatenate([e["rew"] for e in episodes]).astype(np.float32),
    )
    np.testing.assert_array_equal(
        td["next", "terminated"].squeeze(-1).numpy(), np.concatenate([e["term"] for e in episodes])
    )
    np.testing.assert_array_equal(
        td["next", "truncated"].squeeze(-1).numpy(), np.concatenate([e["trunc"] for e in episodes])
    )
    assert torch.equal(td["episode"], torch.arange(45) // 15)
    assert (data.reference_min, data.reference_max) == (1.0, 5.0)
    assert data.normalized_score(3.0) == 50.0
    assert data.metadata["observation_keys"] == ["observation", "desired_goal"]
    assert td["observation"].abs().sum() > 0  # TorchRL 0.14.1's loader returned zeros


def test_discrete_spaces_become_one_hot_vectors_and_missing_references_are_none():
    env = gym.make("FrozenLake-v1", map_name="4x4", is_slippery=True, max_episode_steps=30)
    buffers, episodes = _collect(env, 4)
    _create("test/frozenlake/tiny-v0", buffers, env)

    data = load_minari_dataset("test/frozenlake/tiny-v0")
    td = data.transitions
    states = np.concatenate([ep["obs"][:-1] for ep in episodes])
    actions = np.concatenate([ep["act"] for ep in episodes])
    assert torch.equal(td["observation"].argmax(-1), torch.as_tensor(states))
    assert torch.equal(td["action"], torch.eye(4)[torch.as_tensor(actions)])
    assert data.reference_min is None or data.reference_max is None
    with pytest.raises(ValueError, match="No reference scores"):
        data.normalized_score(1.0)


def test_missing_dataset_error_names_the_download_command():
    with pytest.raises(FileNotFoundError, match="minari download D4RL/antmaze/umaze-v1"):
        load_minari_dataset("D4RL/antmaze/umaze-v1")


def test_antmaze_keeps_the_torso_position_and_pointmaze_does_not_duplicate_it():
    keys = ["achieved_goal", "desired_goal", "observation"]
    assert default_observation_keys(keys, "AntMaze_UMaze-v5") == keys[:1] + keys[2:] + keys[1:2]
    assert default_observation_keys(keys, "PointMaze_Large-v3") == ["observation", "desired_goal"]
    assert default_observation_keys(["b", "a"]) == ["a", "b"]


def test_minari_download_s_default_remote_has_its_client():
    """``pip install ".[minari]"`` installs ``minari[hf]``: Minari's default remote
    (``hf://farama-minari``) needs ``huggingface_hub``, without which ``minari download``
    ends in an ImportError before any network step. Building the client needs no network."""
    from importlib.metadata import requires

    from minari.storage.remotes import DEFAULT_REMOTE, get_cloud_storage

    assert DEFAULT_REMOTE.startswith("hf://")
    assert type(get_cloud_storage()).__name__ == "HuggingFaceStorage"
    for extra in ("minari", "test"):
        (requirement,) = [
            r for r in requires("torchrl-dual") if r.startswith("minari[") and f'"{extra}"' in r
        ]
        assert "hf" in requirement.split("[")[1].split("]")[0].split(","), requirement
