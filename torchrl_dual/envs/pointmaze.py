"""PointMaze (Gymnasium-Robotics) environment factories in the D4RL maze2d style.

The policy reads one flat float32 ``"observation"`` of size 6: the point's state
``(x, y, vx, vy)`` followed by the task goal ``(gx, gy)``.

Conventions (the Gymnasium-Robotics defaults, which mirror D4RL ``maze2d``):

* sparse reward: 1 while the point is within 0.45 of the goal, 0 otherwise;
* ``continuing_task=True``: reaching the goal does not terminate the episode and the
  goal stays where it is (``reset_target=False``), so an episode always runs for
  ``max_episode_steps`` steps (300 for ``umaze``, 600 for ``medium``, 800 for ``large``)
  and ends with ``truncated=True``. A return is therefore "steps spent at the goal".
  Pass ``continuing_task=False`` to terminate on success instead.
* goal: a random open cell per episode (Gymnasium-Robotics); ``goal_cell=(row, col)``
  fixes it, as D4RL maze2d fixes one target per maze (the start stays random), which
  makes the task single-goal instead of goal-conditioned.
* start: a random open cell other than the goal's (Gymnasium-Robotics);
  ``start_avoid_cells`` leaves given cells out (:func:`~torchrl_dual.envs.start_cells`),
  e.g. the region the offline data never enter, so that no episode starts inside the
  task's unexplored part.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from torchrl_dual.envs.flat_observation import reward_transforms
from torchrl_dual.envs.maze_cells import pointmaze_env_id, task_maze_map
from torchrl_dual.envs.maze_xml import release_maze_xml
from torchrl_dual.envs.robotics import register_robotics_envs
from torchrl_dual.envs.shifts import apply_shift, check_shift

POINTMAZE_OBS_KEYS: tuple[str, str] = ("observation", "desired_goal")
"""Entries of the Gymnasium dict observation concatenated (in this order) by the factories."""

_REWARD_TYPES = ("sparse", "dense")


def _gym_kwargs(
    maze: str,
    max_episode_steps: int | None,
    continuing_task: bool,
    reward_type: str,
    goal_cell: Sequence[int] | None = None,
    start_avoid_cells: Sequence[Sequence[int]] | None = None,
) -> tuple[str, dict[str, Any]]:
    env_id = pointmaze_env_id(maze)
    if reward_type not in _REWARD_TYPES:
        raise ValueError(f"reward_type must be one of {_REWARD_TYPES}, got {reward_type!r}.")
    if max_episode_steps is not None and max_episode_steps <= 0:
        raise ValueError(f"max_episode_steps must be positive, got {max_episode_steps}.")
    kwargs: dict[str, Any] = {
        "continuing_task": continuing_task,
        "reset_target": False,
        "reward_type": reward_type,
    }
    if max_episode_steps is not None:
        kwargs["max_episode_steps"] = int(max_episode_steps)
    if goal_cell is not None or start_avoid_cells:
        kwargs["maze_map"] = task_maze_map(maze, goal_cell, start_avoid_cells)
    return env_id, kwargs


def make_pointmaze_gym_env(
    maze: str = "umaze",
    *,
    max_episode_steps: int | None = None,
    continuing_task: bool = True,
    reward_type: str = "sparse",
    shift: str = "none",
    shift_angle: float | None = None,
    shift_scale: float | None = None,
    goal_cell: Sequence[int] | None = None,
    start_avoid_cells: Sequence[Sequence[int]] | None = None,
) -> gym.Env:
    """Builds the raw Gymnasium PointMaze env (dict observations) with the factory's settings.

    Used by the offline data generator so that data and evaluation share one definition.
    Flatten its observations with :func:`flatten_pointmaze_obs`.

    Args:
        maze (str): ``"umaze"``, ``"medium"`` or ``"large"``.
        max_episode_steps (int, optional): time limit; defaults to the registered one.
        continuing_task (bool): keep running after the goal is reached. Defaults to ``True``.
        reward_type (str): ``"sparse"`` (default) or ``"dense"``.
        shift (str): an online dynamics shift of :data:`~torchrl_dual.envs.SHIFTS`
            (``"none"``, ``"rotation"``, ``"damping"``, ``"mass"``). Defaults to ``"none"``.
        shift_angle (float, optional): degrees of ``"rotation"`` (60 by default).
        shift_scale (float, optional): factor of ``"damping"`` / ``"mass"`` (the
            shift's default if ``None``).
        goal_cell (sequence of int, optional): ``(row, col)`` of a fixed goal cell
            (:func:`~torchrl_dual.envs.goal_maze_map`); ``None`` (default): a random open
            cell per episode.
        start_avoid_cells (sequence of (row, col), optional): open cells where no episode
            starts (:func:`~torchrl_dual.envs.start_cells`); ``None`` (default): none.

    Examples:
        >>> env = make_pointmaze_gym_env("umaze", max_episode_steps=5)
        >>> obs, _ = env.reset(seed=0)
        >>> flatten_pointmaze_obs(obs).shape
        (6,)
    """
    register_robotics_envs()
    env_id, kwargs = _gym_kwargs(
        maze, max_episode_steps, continuing_task, reward_type, goal_cell, start_avoid_cells
    )
    check_shift(shift, "pointmaze")
    return apply_shift(
        release_maze_xml(gym.make(env_id, **kwargs)),
        shift,
        angle=shift_angle,
        scale=shift_scale,
        kind="pointmaze",
    )


def flatten_pointmaze_obs(obs: dict[str, np.ndarray]) -> np.ndarray:
    """Concatenates ``observation`` (4) and ``desired_goal`` (2) into a float32 vector.

    Works on single observations and on batches (concatenation on the last axis); the
    result equals the ``"observation"`` written by :func:`make_pointmaze_env`.

    Args:
        obs (dict): a PointMaze observation, or a batch of them (arrays with leading dims).

    Returns:
        np.ndarray: float32 ``[..., 6]``.

    Examples:
        >>> obs = {"observation": np.zeros(4), "desired_goal": np.ones(2), "achieved_goal": np.zeros(2)}
        >>> flatten_pointmaze_obs(obs)
        array([0., 0., 0., 0., 1., 1.], dtype=float32)
    """
    return np.concatenate(
        [np.asarray(obs[k], dtype=np.float32) for k in POINTMAZE_OBS_KEYS], axis=-1
    )


def make_pointmaze_env(
    maze: str = "umaze",
    *,
    max_episode_steps: int | None = None,
    device: torch.device | str = "cpu",
    seed: int | None = None,
    continuing_task: bool = True,
    reward_type: str = "sparse",
    shift: str = "none",
    shift_angle: float | None = None,
    shift_scale: float | None = None,
    goal_cell: Sequence[int] | None = None,
    start_avoid_cells: Sequence[Sequence[int]] | None = None,
    reward_scale: float = 1.0,
    reward_shift: float = 0.0,
):
    """Creates a TorchRL PointMaze environment with a flat float32 ``"observation"``.

    The env is a :class:`~torchrl.envs.GymEnv` over ``PointMaze_<Layout>-v3`` with the
    transforms ``DoubleToFloat`` -> ``CatTensors(observation, desired_goal -> observation)``
    -> ``ExcludeTransform(achieved_goal)`` (it equals ``observation[:2]``) -> ``StepCounter``.
    See the module docstring for reward and termination conventions.

    Args:
        maze (str): ``"umaze"``, ``"medium"`` or ``"large"``.

    Keyword Args:
        max_episode_steps (int, optional): time limit (truncation). Defaults to the
            Gymnasium-Robotics value (300 / 600 / 800).
        device (torch.device or str): device of the output tensordicts. Defaults to ``"cpu"``.
        seed (int, optional): seed passed to :meth:`~torchrl.envs.EnvBase.set_seed`.
        continuing_task (bool): if ``True`` (default, D4RL maze2d style) reaching the goal
            does not end the episode; if ``False`` the episode terminates on success.
        reward_type (str): ``"sparse"`` (default) or ``"dense"`` (``exp(-distance)``).
        shift (str): online dynamics shift (see :func:`make_pointmaze_gym_env`); with a
            shift the base env is a :class:`~torchrl.envs.GymWrapper` around the shifted
            Gymnasium env. Defaults to ``"none"``.
        shift_angle (float, optional): degrees of ``"rotation"`` (60 by default).
        shift_scale (float, optional): factor of ``"damping"`` / ``"mass"``.
        goal_cell (sequence of int, optional): ``(row, col)`` of a fixed goal cell;
            ``None`` (default): a random open cell per episode.
        start_avoid_cells (sequence of (row, col), optional): open cells where no episode
            starts (:func:`~torchrl_dual.envs.start_cells`); ``None`` (default): every open
            cell but the goal's.
        reward_scale (float): the reward becomes ``reward_scale * r + reward_shift``
            (``RewardScaling`` after ``DoubleToFloat``; e.g. Cal-QL's sparse ``10 r - 5``).
            Defaults to 1.
        reward_shift (float): see ``reward_scale``. Defaults to 0.

    Raises:
        ValueError: unknown maze name (the message lists the valid ones), reward type,
            shift, goal cell or start cells.

    Examples:
        >>> env = make_pointmaze_env("umaze", max_episode_steps=20, seed=0)
        >>> env.observation_spec["observation"].shape
        torch.Size([6])
        >>> rollout = env.rollout(10)
        >>> rollout["next", "reward"].shape, rollout["observation"].dtype
        (torch.Size([10, 1]), torch.float32)
    """
    from torchrl.envs import (
        CatTensors,
        Compose,
        DoubleToFloat,
        ExcludeTransform,
        GymWrapper,
        StepCounter,
        TransformedEnv,
    )

    register_robotics_envs()
    env_id, kwargs = _gym_kwargs(
        maze, max_episode_steps, continuing_task, reward_type, goal_cell, start_avoid_cells
    )
    check_shift(shift, "pointmaze")
    gym_env = release_maze_xml(gym.make(env_id, **kwargs))
    if shift != "none":
        gym_env = apply_shift(
            gym_env, shift, angle=shift_angle, scale=shift_scale, kind="pointmaze"
        )
    base = GymWrapper(gym_env, device=device)
    env = TransformedEnv(
        base,
        Compose(
            DoubleToFloat(),
            *reward_transforms(reward_scale, reward_shift),
            CatTensors(
                in_keys=list(POINTMAZE_OBS_KEYS), out_key="observation", del_keys=True, sort=False
            ),
            ExcludeTransform("achieved_goal"),
            StepCounter(),
        ),
    )
    if seed is not None:
        env.set_seed(seed)
    return env
