"""PointMaze factory: flat observation, D4RL maze2d conventions, clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_dual.data import MazeWaypointController
from torchrl_dual.envs import (
    default_max_episode_steps,
    flatten_pointmaze_obs,
    goal_maze_map,
    make_pointmaze_env,
    make_pointmaze_gym_env,
    open_cells,
)


def test_random_rollout_gives_a_flat_float32_observation_of_state_and_goal():
    env = make_pointmaze_env("umaze", seed=0)
    rollout = env.rollout(10)
    assert rollout.batch_size == (10,)
    assert rollout["observation"].shape == (10, 6)
    assert rollout["observation"].dtype == torch.float32
    assert rollout["next", "observation"].shape == (10, 6)
    assert rollout["next", "reward"].shape == (10, 1)
    assert rollout["next", "step_count"].squeeze(-1).tolist() == list(range(1, 11))
    assert "achieved_goal" not in rollout.keys() and "desired_goal" not in rollout.keys()
    assert env.action_spec.shape == (2,)


def test_observation_is_the_point_state_followed_by_the_task_goal():
    env = make_pointmaze_env("umaze", seed=3)
    td = env.reset()
    inner = env.base_env._env.unwrapped
    expected = np.concatenate([inner.point_env.data.qpos, inner.point_env.data.qvel, inner.goal])
    torch.testing.assert_close(td["observation"], torch.as_tensor(expected, dtype=torch.float32))


def test_unknown_maze_name_raises_a_value_error_listing_the_valid_names():
    with pytest.raises(ValueError, match="Valid names: \\['large', 'medium', 'umaze'\\]"):
        make_pointmaze_env("hexmaze")


def test_unknown_reward_type_raises_a_value_error():
    with pytest.raises(ValueError, match="reward_type"):
        make_pointmaze_env("umaze", reward_type="shaped")


def test_default_episode_is_truncated_at_the_time_limit_and_never_terminated():
    env = make_pointmaze_env("umaze", max_episode_steps=15, seed=0)
    rollout = env.rollout(40)
    assert rollout.batch_size == (15,)
    assert rollout["next", "truncated"].squeeze(-1).tolist() == [False] * 14 + [True]
    assert not rollout["next", "terminated"].any()


def test_registered_time_limits_match_d4rl_maze2d():
    assert [default_max_episode_steps(m) for m in ("umaze", "medium", "large")] == [300, 600, 800]


@pytest.mark.parametrize("maze", ["medium", "large"])
def test_larger_layouts_build_and_reset(maze):
    td = make_pointmaze_env(maze, seed=0).reset()
    assert td["observation"].shape == (6,)


def test_same_seed_gives_the_same_rollout():
    def run():
        torch.manual_seed(0)
        return make_pointmaze_env("umaze", seed=7).rollout(20)

    torch.testing.assert_close(run()["next", "observation"], run()["next", "observation"])


def test_sparse_reward_is_one_within_045_of_the_goal():
    env = make_pointmaze_env("umaze", seed=1)
    rollout = env.rollout(50)
    nxt = rollout["next", "observation"]
    close = (nxt[:, :2] - nxt[:, 4:]).norm(dim=-1) <= 0.45
    assert torch.equal(rollout["next", "reward"].squeeze(-1), close.float())


def test_episodic_task_terminates_when_the_goal_is_reached():
    env = make_pointmaze_gym_env("umaze", continuing_task=False, max_episode_steps=300)
    maze = env.unwrapped.maze
    ctrl = MazeWaypointController(maze.maze_map, action_noise=0.0)
    obs, _ = env.reset(seed=0)
    for _ in range(300):
        state = obs["observation"]
        obs, reward, terminated, truncated, _ = env.step(
            ctrl.act(state[:2], state[2:4], obs["desired_goal"])
        )
        if terminated or truncated:
            break
    assert terminated and reward == 1.0
    assert flatten_pointmaze_obs(obs).shape == (6,)


def _cell_of(env, xy: np.ndarray) -> tuple[int, int]:
    maze = env.unwrapped.maze
    row, col = maze.cell_xy_to_rowcol(np.asarray(xy))
    return int(row), int(col)


def test_a_goal_cell_fixes_every_episodes_goal_and_only_the_goal():
    """``goal_cell``: the goal lies in that cell at every reset (D4RL maze2d style), the
    start stays random among the other open cells; without it the goal cell varies."""
    fixed = make_pointmaze_gym_env("medium", goal_cell=(6, 6))
    free = make_pointmaze_gym_env("medium")
    goals, starts, free_goals = set(), set(), set()
    for seed in range(12):
        obs, _ = fixed.reset(seed=seed)
        goals.add(_cell_of(fixed, obs["desired_goal"]))
        starts.add(_cell_of(fixed, obs["achieved_goal"]))
        free_obs, _ = free.reset(seed=seed)
        free_goals.add(_cell_of(free, free_obs["desired_goal"]))
    assert goals == {(6, 6)}
    assert len(starts) > 4 and (6, 6) not in starts
    assert len(free_goals) > 4
    assert open_cells("umaze") == [(1, 1), (1, 2), (1, 3), (2, 3), (3, 1), (3, 2), (3, 3)]


@pytest.mark.parametrize("cell", [(0, 0), (3, 1), (9, 9), (6,)])
def test_a_goal_cell_that_is_not_an_open_cell_names_the_open_cells(cell):
    with pytest.raises(
        ValueError, match=r"not an open cell of the medium maze.*open cells: \[\[1, 1\]"
    ):
        make_pointmaze_env("medium", goal_cell=cell)
    assert goal_maze_map("medium", (6, 6))[6][6] == "g"
