"""``evaluate_episodes`` with kept envs: an evaluator builds its envs once, and a kept env's
episode is the one a new env gives, bit for bit (each reset is seeded whole)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

from torchrl_dual.envs import LocomotionShift, flatten_pointmaze_obs, make_pointmaze_gym_env
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.recipe import CONFIG_DIR, compose_checked
from torchrl_dual.recipe.kits import build as env_kits
from torchrl_dual.recipe.kits import pointmaze as pointmaze_kit

ENVS = {
    "pointmaze": (
        lambda: make_pointmaze_gym_env("medium", max_episode_steps=40, reward_type="dense"),
        flatten_pointmaze_obs,
        2,
    ),
    "hopper_gravity": (
        lambda: LocomotionShift(gym.make("Hopper-v5", max_episode_steps=40), "gravity", 0.5),
        lambda obs: obs,
        3,
    ),
}


def _policy(action_dim: int) -> TensorDictModule:
    """Deterministic actions that depend on the state, so that episodes differ."""
    act = lambda o: torch.sin(3.0 * o[..., :action_dim])  # noqa: E731
    return TensorDictModule(act, in_keys=["observation"], out_keys=["action"])


@pytest.mark.parametrize("name", sorted(ENVS))
def test_kept_envs_are_built_once_and_give_the_returns_of_new_ones(name):
    make_env, observation_fn, action_dim = ENVS[name]
    built = []

    def counted() -> gym.Env:
        built.append(make_env())
        return built[-1]

    def returns(episodes: int, envs: list | None, make=make_env) -> np.ndarray:
        policy = _policy(action_dim)
        return evaluate_episodes(
            make, policy, episodes, observation_fn=observation_fn, seed=7, envs=envs
        )

    new = returns(4, None)
    assert len(set(new.tolist())) == 4  # the episodes differ: the comparison can fail
    kept: list = []
    first, again = returns(3, kept, counted), returns(3, kept, counted)
    assert len(built) == 3 and kept == built
    np.testing.assert_array_equal(first, new[:3])
    np.testing.assert_array_equal(again, new[:3])
    np.testing.assert_array_equal(returns(4, kept, counted), new)  # one more built
    assert len(built) == 4


def test_the_pointmaze_evaluator_builds_its_envs_at_the_first_evaluation_only(
    tmp_path, monkeypatch
):
    cfg = compose_checked(
        CONFIG_DIR,
        ["algo=iql", "budget=smoke", "budget.eval_episodes=3", "env.max_episode_steps=5",
         "env.shift=rotation", f"output_dir={tmp_path}"],
    )  # fmt: skip
    built = []

    def counted(*args, **kwargs) -> gym.Env:
        built.append(make_pointmaze_gym_env(*args, **kwargs))
        return built[-1]

    monkeypatch.setattr(pointmaze_kit, "make_pointmaze_gym_env", counted)
    data = type("Scores", (), {"normalized_score": staticmethod(lambda r: r)})()
    evaluate = env_kits.make_evaluator(cfg, data)
    results = [evaluate(_policy(2)) for _ in range(3)]
    assert len(built) == 2 * 3  # the shifted envs and the unshifted ones, 3 episodes each
    assert results[0] == results[1] == results[2]
