"""The builders of the PointMaze and Frozen-Lake env kits, and what every run asks of its kit.

Algorithm 1 line 1: :func:`make_offline_dataset`, :func:`make_train_env`,
:class:`TrainEnvFactory`, :func:`make_evaluator`, :func:`projected_policy`.

The table of kits, :data:`~torchrl_dual.recipe.settings.envs.ENV_KITS`, names these
builders (and the Minari families' in :mod:`~torchrl_dual.recipe.kits.minari_families`)
next to each kind's ``env.*`` schema.

``env.shift`` (a :data:`~torchrl_dual.envs.SHIFTS` name, ``none`` by default) changes
the dynamics of the online env and of the evaluation env, never of the env the offline
data comes from (the data and its cache entry do not depend on it). With a shift the
evaluator reports the score under the shift (``normalized_score``, what a run is judged
on) and without it (``normalized_score_unshifted``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual._utils import one_hot_at
from torchrl_dual.data import (
    MazeWaypointController,
    OfflineDataset,
    load_or_generate_frozenlake_dataset,
    load_or_generate_maze_dataset,
    validate_transitions,
)
from torchrl_dual.data.cache import default_cache_dir
from torchrl_dual.envs import (
    flatten_pointmaze_obs,
    frozenlake_num_states,
    frozenlake_success_probability,
    goal_maze_map,
    make_frozenlake_env,
    make_pointmaze_env,
    make_pointmaze_gym_env,
    open_cells,
    start_cells,
    vectorized_env,
)
from torchrl_dual.evaluation import evaluate_episodes, frozenlake_policy_actions
from torchrl_dual.recipe.settings.envs import ENV_KITS, EnvKit
from torchrl_dual.recipe.settings.errors import ConfigError, UserError, warn
from torchrl_dual.recipe.settings.structured import RecipeSettings
from torchrl_dual.transforms import PreviousTransition

Evaluator = Callable[[nn.Module], dict[str, float]]
"""``policy -> {"return": ..., "normalized_score": ..., ...}`` under deterministic actions
(``normalized_score`` is NaN when the data set has no reference returns)."""


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


def _pointmaze_shift(env: DictConfig) -> dict[str, Any]:
    return {"shift": env.shift, "shift_angle": env.shift_angle, "shift_scale": env.shift_scale}


def _pointmaze_goal(env: DictConfig) -> list[int] | None:
    return None if env.goal_cell is None else list(env.goal_cell)


def _pointmaze_avoided(env: DictConfig, key: str = "data_avoid_cells") -> list[list[int]] | None:
    cells = env.get(key)
    return None if not cells else [list(cell) for cell in cells]


def _pointmaze_starts_avoided(env: DictConfig) -> list[list[int]] | None:
    return _pointmaze_avoided(env, "start_avoid_cells")


def pointmaze_data(cfg: DictConfig) -> OfflineDataset:
    """The PointMaze kit's ``D_offline``: controller episodes of ``env.maze``, cached on disk.

    The data are generated (or loaded from ``cfg.data_cache_dir``) with
    ``budget.dataset_transitions`` transitions; the rewards are scaled and shifted as
    the online env's are.
    """
    env = cfg.env
    data = load_or_generate_maze_dataset(
        env.maze,
        cfg.budget.dataset_transitions,
        cfg.seed,
        cfg.data_cache_dir,
        max_episode_steps=env.max_episode_steps,
        goal_cell=_pointmaze_goal(env),
        avoid_cells=_pointmaze_avoided(env),
    )
    if env.reward_scale != 1.0 or env.reward_shift != 0.0:  # as the online env's RewardScaling
        reward = data.transitions["next", "reward"]
        data.transitions["next", "reward"] = reward * env.reward_scale + env.reward_shift
    return data


def pointmaze_env(cfg: DictConfig, data: OfflineDataset | None) -> EnvBase:
    """The PointMaze kit's online env, with the config's goal, starts, reward and shift."""
    env = cfg.env
    return make_pointmaze_env(
        env.maze,
        max_episode_steps=env.max_episode_steps,
        seed=cfg.seed,
        device="cpu",
        goal_cell=_pointmaze_goal(env),
        start_avoid_cells=_pointmaze_starts_avoided(env),
        reward_scale=env.reward_scale,
        reward_shift=env.reward_shift,
        **_pointmaze_shift(env),
    )


def pointmaze_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
    """The PointMaze kit's evaluator: deterministic episodes, scored by the data's references.

    Runs ``budget.eval_episodes`` episodes in the shifted env (and, under ``env.shift``, in
    the unshifted one too); the envs are built at the first evaluation and kept.
    """
    env = cfg.env
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
            cfg.budget.eval_episodes,
            observation_fn=flatten_pointmaze_obs,
            action_fn=lambda a: np.clip(a, -1.0, 1.0),
            seed=10_000 + cfg.seed,
            device=cfg.device,
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


def pointmaze_start_distances(env: DictConfig) -> dict[str, dict[int, int]]:
    """How far the episodes of a PointMaze ``env.*`` config start from the goal and avoided cells.

    The online env's and the evaluator's, which share the reset: ``{"goal": {moves:
    start cells}, "avoided": {moves: start cells}}``, the shortest path in cell moves
    through the maze from each start cell of the env (its Gymnasium-Robotics reset
    cells, equally likely) to ``env.goal_cell`` and to the nearest
    ``env.data_avoid_cells`` cell (0: inside them); an entry is left out when its key is
    null. Start cells over all of them is the share of episodes.

    Examples:
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


def frozenlake_data(cfg: DictConfig) -> OfflineDataset:
    """The Frozen-Lake kit's ``D_offline``: epsilon-greedy episodes, cached on disk."""
    env = cfg.env
    return load_or_generate_frozenlake_dataset(
        env.map_name,
        cfg.budget.dataset_transitions,
        cfg.seed,
        cfg.data_cache_dir,
        success_rate=env.offline_success_rate,
        eval_success_rate=env.online_success_rate,
        epsilon=env.epsilon,
        max_episode_steps=env.max_episode_steps,
    )


def frozenlake_env(cfg: DictConfig, data: OfflineDataset | None) -> EnvBase:
    """The Frozen-Lake kit's online env, at ``env.online_success_rate`` and ``env.shift``."""
    env = cfg.env
    return make_frozenlake_env(
        env.map_name,
        success_rate=env.online_success_rate,
        seed=cfg.seed,
        max_episode_steps=env.max_episode_steps,
        shift=env.shift,
    )


def frozenlake_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
    """The exact success probability of the greedy policy (value iteration, no sampling)."""
    env = cfg.env
    num_states = frozenlake_num_states(env.map_name)

    def success(actions: np.ndarray, shift: str) -> float:
        return float(
            frozenlake_success_probability(
                actions,
                env.map_name,
                env.online_success_rate,
                horizon=env.max_episode_steps,
                shift=shift,
            )
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        actions = frozenlake_policy_actions(policy, num_states, cfg.device)
        shifted = success(actions, env.shift)
        result = {"return": shifted, "normalized_score": float(data.normalized_score(shifted))}
        if env.shift != "none":
            plain = success(actions, "none")
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = float(data.normalized_score(plain))
        return result

    return evaluate


def one_hot_argmax(action: torch.Tensor) -> torch.Tensor:
    """The executed discrete action as the one-hot vector the env receives, without a host read."""
    return one_hot_at(action.argmax(-1, keepdim=True), action, -1)


def env_kit(cfg: DictConfig | RecipeSettings) -> EnvKit:
    """The :class:`EnvKit` of ``cfg.env.kind`` (the config, or the run's typed settings)."""
    return ENV_KITS[cfg.env.kind]


def make_offline_dataset(cfg: DictConfig) -> OfflineDataset:
    """``D_offline`` from the cache (or generated and cached), checked (Alg. 1 line 1)."""
    data = env_kit(cfg).load_data(cfg)
    try:
        validate_transitions(data.transitions)
    except ValueError as err:
        cache = cfg.data_cache_dir if cfg.data_cache_dir is not None else default_cache_dir()
        raise UserError(
            "data_cache_dir",
            cache,
            f"the cached offline data of env={cfg.env.name} is invalid: {err} Delete its "
            "entry in the cache to regenerate it.",
        ) from err
    warn_if_batches_exceed_data(cfg, len(data))
    return data


def warn_if_batches_exceed_data(cfg: DictConfig, transitions: int) -> None:
    """Warns when an update's batch is larger than ``D_offline``.

    One ``warning:`` line when an update draws more transitions (``online.batch_size``)
    or windows (``planner.batch_size``) than ``D_offline`` holds: sampled with
    replacement, such a batch repeats the data many times over at a cost that grows with
    its size.
    """
    for section in ("online", "planner"):
        node = cfg.get(section)
        if node is None or node.get("batch_size", 0) <= transitions:
            continue
        batch = node.batch_size
        interpolated = OmegaConf.is_interpolation(node, "batch_size")  # the budget's value
        name = "budget.batch_size" if interpolated else f"{section}.batch_size"
        warn(
            f"{name}={batch} exceeds the {transitions} transitions of the offline data: "
            f"drawn with replacement, a batch holds each about {batch / transitions:.0f} "
            f"times and every update pays for all {batch}; lower it to at most {transitions}"
        )
        return


def projected_policy(cfg: DictConfig | RecipeSettings, policy: nn.Module) -> nn.Module:
    """``policy`` followed by the env kit's ``action_projection``, or ``policy`` itself.

    The projection gives the executed action the replay buffer stores, e.g.
    Frozen-Lake's one-hot argmax.
    """
    projection = env_kit(cfg).action_projection
    if projection is None:
        return policy
    return TensorDictSequential(
        policy, TensorDictModule(projection, in_keys=["action"], out_keys=["action"])
    )


def make_train_env(cfg: DictConfig, data: OfflineDataset | None = None) -> EnvBase:
    """The online env with :class:`PreviousTransition`, which carries ``(s_{t-1}, a_{t-1})``.

    The policy turns them into ``d_t`` of Eq. (10). ``data`` is ``D_offline`` when the
    caller has it (kits whose env depends on it read it otherwise).
    """
    return env_kit(cfg).make_env(cfg, data).append_transform(PreviousTransition())


def make_collection_env(cfg: DictConfig, data: OfflineDataset | None, env: EnvBase) -> EnvBase:
    """The env ``collector=single`` steps: the online env, or ``N`` copies of it as one batch.

    With ``collector.num_envs = N > 1``, ``N`` more copies of ``env``
    (:func:`make_train_env`) are stepped as one batch ``[N]``
    (:func:`~torchrl_dual.envs.vectorized_env`: one Gymnasium vector env, each copy with
    the kit's Gymnasium wrappers, the transforms once over the batch).
    """
    num_envs = cfg.collector.get("num_envs", 1)
    if num_envs == 1:
        return env
    return vectorized_env(lambda: make_train_env(cfg, data), num_envs)


class TrainEnvFactory:
    """``() -> env``: the online env of ``cfg`` (with ``PreviousTransition``), picklable.

    It holds the resolved config as plain containers and the offline data set without its
    transitions (:meth:`~torchrl_dual.data.OfflineDataset.without_transitions`), so a
    spawned worker process (or a Ray actor) receives a few kilobytes rather than the run's
    offline data; kits whose env depends on the data (the Minari kits' observation
    normalization and reward scale) find it in that description. Without ``data`` they
    read the data set again in each worker.

    Args:
        cfg (DictConfig): a validated recipe config.
        data (OfflineDataset, optional): the run's ``D_offline``.

    Examples:
        >>> import pickle
        >>> env = {"kind": "pointmaze", "maze": "umaze", "max_episode_steps": 20}
        >>> env.update(shift="none", shift_angle=0.0, shift_scale=None, goal_cell=None,
        ...     reward_scale=1.0, reward_shift=0.0)
        >>> cfg = OmegaConf.create({"seed": 0, "env": env})  # what the PointMaze kit reads
        >>> factory = pickle.loads(pickle.dumps(TrainEnvFactory(cfg)))
        >>> env = factory()
        >>> "previous_observation" in env.reset().keys()
        True
    """

    def __init__(self, cfg: DictConfig, data: OfflineDataset | None = None) -> None:
        self.config = OmegaConf.to_container(cfg, resolve=True)
        self.data = None if data is None else data.without_transitions()

    def __call__(self) -> EnvBase:
        """A fresh online env built from the stored config and data (in a worker process)."""
        return make_train_env(OmegaConf.create(self.config), self.data)


def check_dims(env: EnvBase, data: OfflineDataset, name: Any = None) -> None:
    """Fails when the data set and the env disagree on observation or action size."""
    obs_dim = env.observation_spec["observation"].shape[-1]
    action_dim = env.action_spec.shape[-1]
    if (data.obs_dim, data.action_dim) != (obs_dim, action_dim):
        raise UserError(
            None if name is None else "env",
            name,
            f"the offline data has observation/action dims ({data.obs_dim}, "
            f"{data.action_dim}) but the env has ({obs_dim}, {action_dim}). Regenerate the "
            "data for this env (delete its cache entry) or pick the matching env.",
        )


def make_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
    """Deterministic evaluation returning the mean return and the normalized score."""
    return env_kit(cfg).make_evaluator(cfg, data)
