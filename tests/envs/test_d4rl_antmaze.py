"""D4RL's single-goal AntMaze task on Gymnasium-Robotics' AntMaze (``env.protocol=d4rl``):
where the task's start and goal land in Minari's maze, the wrapper's reward, termination
and reset, and a scripted controller that reaches the goal against a random policy."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium_robotics.envs.maze.maps import LARGE_MAZE, MEDIUM_MAZE, U_MAZE

from torchrl_dual.data import MazeWaypointController
from torchrl_dual.data.minari_standins import UMAZE_EVAL_MAP, UMAZE_MAP
from torchrl_dual.envs import register_robotics_envs, release_maze_xml
from torchrl_dual.envs.d4rl_antmaze import (
    D4RL_ANTMAZE_MAPS,
    D4RL_SUCCESS_RADIUS,
    D4RLAntMazeTask,
    SingleGoalAntMaze,
    d4rl_maze_of,
)


def make_env(maze_map, steps: int = 700, **task_kwargs) -> SingleGoalAntMaze:
    register_robotics_envs()
    raw = release_maze_xml(
        gym.make(
            "AntMaze_UMaze-v4",
            maze_map=maze_map,
            continuing_task=True,
            reset_target=False,
            max_episode_steps=steps,
        )
    )
    task = D4RLAntMazeTask.for_maze(
        task_kwargs.pop("maze", "umaze"), maze_map, maze_size_scaling=4.0
    )
    return SingleGoalAntMaze(raw, task, **task_kwargs)


def test_the_umaze_task_is_d4rl_s_in_minari_s_upside_down_map():
    """Minari's U-maze data map is D4RL's ``U_MAZE_TEST`` with the rows reversed (the two
    libraries draw rows in opposite y directions), so the task keeps D4RL's geometry: start
    at the bottom-left cell (-4, -4), goal at the top-left cell's centre (-4, 4) plus D4RL's
    mean goal offset (+0.75, +0.75), 8 units up the maze's left side."""
    task = D4RLAntMazeTask.for_maze("umaze", UMAZE_MAP, maze_size_scaling=4.0)
    assert task.reset_cell == (3, 1) and task.goal_cell == (1, 1)
    assert task.goal.tolist() == [-3.25, 4.75]
    assert task.max_episode_steps == 700
    # umaze-diverse's map (Gymnasium-Robotics' U_MAZE: no markers, the same walls both ways)
    # poses the same task, and D4RL's rows as they are (with their markers) the mirror image
    diverse = D4RLAntMazeTask.for_maze("umaze", U_MAZE, maze_size_scaling=4.0)
    assert diverse.reset_cell == (3, 1) and diverse.goal.tolist() == task.goal.tolist()
    mirrored = D4RLAntMazeTask.for_maze("umaze", D4RL_ANTMAZE_MAPS["umaze"], maze_size_scaling=4.0)
    assert mirrored.reset_cell == (1, 1) and mirrored.goal.tolist() == [-3.25, -4.75]


@pytest.mark.parametrize(
    "maze, env_map, goal_cell, centre",
    [("medium", MEDIUM_MAZE, (6, 6), (10.0, -10.0)), ("large", LARGE_MAZE, (7, 9), (14.0, -12.0))],
)
def test_a_map_with_d4rl_s_rows_carries_the_goal_offset_downwards(maze, env_map, goal_cell, centre):
    """With D4RL's rows as they are (Gymnasium-Robotics' own MEDIUM/LARGE maps), D4RL's
    ``+y`` (its next row) is the world's ``-y``: the goal offset points down."""
    task = D4RLAntMazeTask.for_maze(maze, env_map, maze_size_scaling=4.0)
    assert task.goal_cell == goal_cell and task.reset_cell == (1, 1)
    assert task.goal.tolist() == [centre[0] + 0.75, centre[1] - 0.75]
    assert task.max_episode_steps == 1000


def test_a_maze_other_than_d4rl_s_is_refused():
    with pytest.raises(ValueError, match="not D4RL's antmaze-medium"):
        D4RLAntMazeTask.for_maze("medium", LARGE_MAZE, maze_size_scaling=4.0)
    with pytest.raises(ValueError, match="no D4RL AntMaze task"):
        d4rl_maze_of("open-dense")
    assert {d4rl_maze_of(d) for d in ("umaze-diverse", "medium-play", "large-diverse")} == set(
        D4RL_ANTMAZE_MAPS
    )


def test_the_goal_noise_is_d4rl_s_square_around_the_fixed_goal():
    """D4RL's ``-v2`` envs draw the goal at each reset in ``[0, 1.5]^2`` from the G cell's
    centre (``U(0, 1) + U(0, 0.5)`` per axis); the fixed goal is that square's mean."""
    task = D4RLAntMazeTask.for_maze("umaze", UMAZE_MAP, maze_size_scaling=4.0)
    goals = np.stack([task.sample_goal(np.random.default_rng(k)) for k in range(4000)])
    offset = goals - np.array([-4.0, 4.0])
    assert offset.min() >= 0.0 and offset.max() <= 1.5
    assert np.allclose(offset.mean(0), 0.75, atol=0.03)


def test_reset_puts_the_ant_at_the_start_and_the_goal_at_the_task_s():
    env = make_env(UMAZE_MAP)
    starts = []
    for seed in range(5):
        obs, info = env.reset(seed=seed)
        starts.append(obs["achieved_goal"])
        assert np.abs(obs["achieved_goal"] - [-4.0, -4.0]).max() <= 0.1  # D4RL's joint noise
        assert obs["desired_goal"].tolist() == [-3.25, 4.75] and info["success"] is False
        assert env.unwrapped.goal.tolist() == [-3.25, 4.75]
    assert len({tuple(xy) for xy in starts}) == 5  # noise, as D4RL's reset_model
    assert np.array_equal(env.reset(seed=3)[0]["achieved_goal"], starts[3])  # seeded
    noisy = make_env(UMAZE_MAP, goal_noise=True)
    goals = {tuple(noisy.reset(seed=s)[0]["desired_goal"]) for s in range(5)}
    assert len(goals) == 5


def scripted_episode(env: SingleGoalAntMaze, seed: int) -> tuple[float, int, bool]:
    """Moves the torso along the maze's shortest path (a kinematic waypoint controller: the
    torso is placed 0.25 x the waypoint controller's action further at each step), until the
    env ends the episode; returns (return, steps, terminated)."""
    controller = MazeWaypointController(
        env.unwrapped.maze.maze_map, maze_size_scaling=4.0, action_noise=0.0
    )
    obs, _ = env.reset(seed=seed)
    ant = env.unwrapped.ant_env
    total, steps = 0.0, 0
    while True:
        xy = obs["achieved_goal"]
        step = controller.act(xy, np.zeros(2), env.task.goal)
        ant.data.qpos[:2] = xy + 0.25 * step
        ant.data.qvel[:] = 0.0
        obs, reward, terminated, truncated, info = env.step(np.zeros(8))
        total, steps = total + reward, steps + 1
        assert info["success"] == terminated == (reward == 1.0)
        if terminated or truncated:
            return total, steps, terminated


def test_a_scripted_controller_scores_100_and_a_random_policy_0():
    """Score = 100 x success rate, as D4RL/CORL (return 1 per successful episode)."""
    env = make_env(UMAZE_MAP)
    scripted = [scripted_episode(env, seed) for seed in range(5)]
    assert all(terminated for _, _, terminated in scripted)
    assert 100 * np.mean([ret for ret, _, _ in scripted]) == 100.0
    assert all(steps < 700 for _, steps, _ in scripted)
    random_returns = []
    for seed in range(3):
        env.reset(seed=seed)
        env.action_space.seed(seed)
        ret, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
            ret, done = ret + reward, terminated or truncated
        random_returns.append(ret)
    assert 100 * np.mean(random_returns) == 0.0


def test_the_episode_ends_at_the_first_step_within_0_5_of_the_goal():
    env = make_env(UMAZE_MAP)
    env.reset(seed=0)
    ant = env.unwrapped.ant_env
    goal = env.task.goal
    for distance, expected in ((0.7, False), (0.3, True)):
        ant.data.qpos[:2] = goal + [distance, 0.0]
        ant.data.qvel[:] = 0.0
        obs, reward, terminated, _, _ = env.step(np.zeros(8))
        near = np.linalg.norm(obs["achieved_goal"] - goal) <= D4RL_SUCCESS_RADIUS
        assert terminated == near == expected and reward == float(expected)


def test_the_evaluation_map_minari_records_is_not_the_task_s_maze():
    """Minari's ``eval_env`` U-maze is the data maze turned 180 degrees (Minari issue #304):
    its walls are neither D4RL's nor D4RL's upside down, so the task refuses it."""
    with pytest.raises(ValueError, match="not D4RL's antmaze-umaze"):
        D4RLAntMazeTask.for_maze("umaze", UMAZE_EVAL_MAP, maze_size_scaling=4.0)
