"""Frozen-Lake factory: one-hot float observation, continuous action executed by argmax."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_dual.envs import make_frozenlake_env

LEFT, DOWN, RIGHT, UP = range(4)


def _step(env, action_index: int, low: float = 0.0) -> TensorDict:
    action = torch.full((4,), low)
    action[action_index] = 0.9
    td = env.reset()
    td["action"] = action
    return env.step(td)


def test_random_rollout_gives_one_hot_float_observations_and_float_actions():
    env = make_frozenlake_env("4x4", success_rate=2 / 3, seed=0)
    rollout = env.rollout(10)
    obs = rollout["observation"]
    assert obs.dtype == torch.float32 and obs.shape[-1] == 16
    assert torch.equal(obs.sum(-1), torch.ones(obs.shape[0]))
    assert rollout["action"].dtype == torch.float32 and rollout["action"].shape[-1] == 4
    assert ((rollout["action"] >= 0) & (rollout["action"] <= 1)).all()


def test_the_env_executes_the_argmax_of_the_action_vector():
    env = make_frozenlake_env("4x4", success_rate=1.0, seed=0)
    assert _step(env, RIGHT)["next", "observation"].argmax().item() == 1
    assert _step(env, DOWN)["next", "observation"].argmax().item() == 4
    assert _step(env, LEFT)["next", "observation"].argmax().item() == 0


def test_action_box_can_be_minus_one_to_one():
    env = make_frozenlake_env("4x4", success_rate=1.0, action_low=-1.0)
    assert env.action_spec.space.low.tolist() == [-1.0] * 4
    assert _step(env, DOWN, low=-1.0)["next", "observation"].argmax().item() == 4


def test_success_rate_reaches_the_gymnasium_env():
    env = make_frozenlake_env("4x4", success_rate=3 / 4)
    probs = sorted(p for p, *_ in env.base_env._env.unwrapped.P[0][RIGHT])
    assert probs == pytest.approx([1 / 8, 1 / 8, 3 / 4])


def test_episode_is_truncated_after_100_steps():
    env = make_frozenlake_env("4x4", success_rate=1.0)

    def always_left(td):
        td["action"] = torch.tensor([1.0, 0.0, 0.0, 0.0])
        return td

    rollout = env.rollout(150, policy=always_left)
    assert rollout.batch_size == (100,)
    assert rollout["next", "truncated"][-1].item() and not rollout["next", "terminated"].any()


def test_eight_by_eight_map_has_64_cells():
    assert make_frozenlake_env("8x8").observation_spec["observation"].shape == (64,)


def test_unknown_map_or_bad_success_rate_raises():
    with pytest.raises(ValueError, match="Valid names"):
        make_frozenlake_env("5x5")
    with pytest.raises(ValueError, match="success_rate"):
        make_frozenlake_env("4x4", success_rate=0.0)
