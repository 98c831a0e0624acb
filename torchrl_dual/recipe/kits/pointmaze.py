"""The PointMaze kit (``env=pointmaze_*``): controller data, online env and evaluator.

The table of kits, :data:`~torchrl_dual.recipe.settings.envs.ENV_KITS`, names these
builders next to the ``env.*`` schema.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from omegaconf import DictConfig
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import MazeWaypointController, OfflineDataset, load_or_generate_maze_dataset
from torchrl_dual.envs import (
    flatten_pointmaze_obs,
    goal_maze_map,
    make_pointmaze_env,
    make_pointmaze_gym_env,
    open_cells,
    start_cells,
)
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.recipe.kits.build import Evaluator
from torchrl_dual.recipe.settings.envs import PointMazeSettings
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.structured import RecipeSettings


def check_pointmaze(cfg: DictConfig) -> None:
    """Checks the PointMaze cells of the config against ``env.maze``.

    ``env.goal_cell`` and every ``env.data_avoid_cells`` and ``env.start_avoid_cells``
    entry are open cells of ``env.maze`` (``[row, col]`` pairs), and the latter leave a
    cell to start in (:func:`~torchrl_dual.envs.start_cells`).
    """
    goal_cell = cfg.env.goal_cell
    if goal_cell is not None:
        try:
            goal_maze_map(cfg.env.maze, list(goal_cell))
        except ValueError as err:
            raise ConfigError("env.goal_cell", list(goal_cell), str(err)) from err
    avoided = _pointmaze_avoided(cfg.env) or []
    for cell in avoided:
        try:
            goal_maze_map(cfg.env.maze, cell)
        except ValueError as err:
            raise ConfigError("env.data_avoid_cells", cell, str(err)) from err
    if avoided and set(open_cells(cfg.env.maze)) <= {tuple(cell) for cell in avoided}:
        raise ConfigError(
            "env.data_avoid_cells",
            avoided,
            f"covers every open cell of the {cfg.env.maze} maze, so the offline data would "
            "have nowhere to go; leave at least one open cell out",
        )
    no_start = _pointmaze_starts_avoided(cfg.env)
    try:
        start_cells(cfg.env.maze, _pointmaze_goal(cfg.env), no_start)
    except ValueError as err:
        raise ConfigError("env.start_avoid_cells", no_start, str(err)) from err


def _pointmaze_shift(env: PointMazeSettings) -> dict[str, Any]:
    return {"shift": env.shift, "shift_angle": env.shift_angle, "shift_scale": env.shift_scale}


def _pointmaze_goal(env: PointMazeSettings) -> list[int] | None:
    return None if env.goal_cell is None else list(env.goal_cell)


def _pointmaze_avoided(
    env: PointMazeSettings, key: str = "data_avoid_cells"
) -> list[list[int]] | None:
    cells = getattr(env, key, None)
    return None if not cells else [list(cell) for cell in cells]


def _pointmaze_starts_avoided(env: PointMazeSettings) -> list[list[int]] | None:
    return _pointmaze_avoided(env, "start_avoid_cells")


def pointmaze_data(settings: RecipeSettings) -> OfflineDataset:
    """The PointMaze kit's ``D_offline``: controller episodes of ``env.maze``, cached on disk.

    The data are generated (or loaded from ``settings.data_cache_dir``) with
    ``budget.dataset_transitions`` transitions; the rewards are scaled and shifted as
    the online env's are.
    """
    env = settings.env
    data = load_or_generate_maze_dataset(
        env.maze,
        settings.budget.dataset_transitions,
        settings.seed,
        settings.data_cache_dir,
        max_episode_steps=env.max_episode_steps,
        goal_cell=_pointmaze_goal(env),
        avoid_cells=_pointmaze_avoided(env),
    )
    if env.reward_scale != 1.0 or env.reward_shift != 0.0:  # as the online env's RewardScaling
        reward = data.transitions["next", "reward"]
        data.transitions["next", "reward"] = reward * env.reward_scale + env.reward_shift
    return data


def pointmaze_env(settings: RecipeSettings, data: OfflineDataset | None) -> EnvBase:
    """The PointMaze kit's online env, with the config's goal, starts, reward and shift."""
    env = settings.env
    return make_pointmaze_env(
        env.maze,
        max_episode_steps=env.max_episode_steps,
        seed=settings.seed,
        device="cpu",
        goal_cell=_pointmaze_goal(env),
        start_avoid_cells=_pointmaze_starts_avoided(env),
        reward_scale=env.reward_scale,
        reward_shift=env.reward_shift,
        **_pointmaze_shift(env),
    )


def pointmaze_evaluator(settings: RecipeSettings, data: OfflineDataset) -> Evaluator:
    """The PointMaze kit's evaluator: deterministic episodes, scored by the data's references.

    Runs ``budget.eval_episodes`` episodes in the shifted env (and, under ``env.shift``, in
    the unshifted one too); the envs are built at the first evaluation and kept.
    """
    env = settings.env
    kept: dict[bool, list] = {True: [], False: []}  # shifted, unshifted

    def returns(policy: nn.Module, shifted: bool) -> np.ndarray:
        return evaluate_episodes(
            lambda: make_pointmaze_gym_env(
                env.maze,
                max_episode_steps=env.max_episode_steps,
                goal_cell=_pointmaze_goal(env),
                start_avoid_cells=_pointmaze_starts_avoided(env),
                **(_pointmaze_shift(env) if shifted else {}),
            ),
            policy,
            settings.budget.eval_episodes,
            observation_fn=flatten_pointmaze_obs,
            action_fn=lambda a: np.clip(a, -1.0, 1.0),
            seed=10_000 + settings.seed,
            device=settings.device,
            envs=kept[shifted],
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        shifted = returns(policy, True)
        mean = float(shifted.mean())
        result = {
            "return": mean,
            "return_std": float(shifted.std()),
            "normalized_score": float(data.normalized_score(mean)),
        }
        if env.shift != "none":
            plain = float(returns(policy, False).mean())
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = float(data.normalized_score(plain))
        return result

    return evaluate


def pointmaze_start_distances(env: PointMazeSettings) -> dict[str, dict[int, int]]:
    """How far the episodes of a PointMaze ``env.*`` config start from the goal and avoided cells.

    The online env's and the evaluator's, which share the reset: ``{"goal": {moves:
    start cells}, "avoided": {moves: start cells}}``, the shortest path in cell moves
    through the maze from each start cell of the env (its Gymnasium-Robotics reset
    cells, equally likely) to ``env.goal_cell`` and to the nearest
    ``env.data_avoid_cells`` cell (0: inside them); an entry is left out when its key is
    null. Start cells over all of them is the share of episodes.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> env = OmegaConf.create({"maze": "umaze", "goal_cell": [3, 1],
        ...     "data_avoid_cells": [[3, 1], [3, 2]], "start_avoid_cells": None})
        >>> pointmaze_start_distances(env)
        {'goal': {1: 1, 2: 1, 3: 1, 4: 1, 5: 1, 6: 1}, 'avoided': {0: 1, 1: 1, 2: 1, 3: 1, 4: 1, 5: 1}}
        >>> env.start_avoid_cells = env.data_avoid_cells  # no start inside them
        >>> pointmaze_start_distances(env)["avoided"]
        {1: 1, 2: 1, 3: 1, 4: 1, 5: 1}
    """
    gym_env = make_pointmaze_gym_env(
        env.maze, goal_cell=_pointmaze_goal(env), start_avoid_cells=_pointmaze_starts_avoided(env)
    )
    maze = gym_env.unwrapped.maze
    paths = MazeWaypointController(maze.maze_map, maze_size_scaling=maze.maze_size_scaling)
    starts = [paths.xy_to_cell(xy) for xy in maze.unique_reset_locations]
    gym_env.close()
    targets = {"goal": [_pointmaze_goal(env)], "avoided": _pointmaze_avoided(env)}
    out = {}
    for name, cells in targets.items():
        if cells and cells[0] is not None:
            moves = [min(paths.path_length(s, tuple(c)) for c in cells) for s in starts]
            out[name] = {d: moves.count(d) for d in sorted(set(moves))}
    return out
