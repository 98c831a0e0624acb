"""The table of environment kits: one entry per ``env.kind`` (Algorithm 1 line 1).

An :class:`EnvKit` holds everything the recipe needs from one kind of environment: the
schema of its ``env.*`` keys, the offline data set ``D_offline``, the online env, the
evaluator returning D4RL-normalized scores, and the projection of the policy's action
onto what the env executes. Adding an environment is adding one entry to
:data:`ENV_KITS` and one ``torchrl_dual/recipe/config/env/<name>.yaml`` that sets ``kind``; nothing
else in the recipe branches on the env.

``env.shift`` (a :data:`~torchrl_dual.envs.SHIFTS` name, ``none`` by default) changes
the dynamics of the online env and of the evaluation env, never of the env the offline
data comes from (the data and its cache entry do not depend on it). With a shift the
evaluator reports the score under the shift (``normalized_score``, what a run is judged
on) and without it (``normalized_score_unshifted``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import (
    OfflineDataset,
    load_or_generate_frozenlake_dataset,
    load_or_generate_maze_dataset,
    validate_transitions,
)
from torchrl_dual.data.cache import default_cache_dir
from torchrl_dual.envs import (
    FROZENLAKE_MAPS,
    POINTMAZE_IDS,
    flatten_pointmaze_obs,
    frozenlake_num_states,
    frozenlake_success_probability,
    goal_maze_map,
    make_frozenlake_env,
    make_pointmaze_env,
    make_pointmaze_gym_env,
    shift_names,
)
from torchrl_dual.evaluation import evaluate_episodes, frozenlake_policy_actions
from torchrl_dual.recipe.kits.kit import EnvKit, EnvSettings, Evaluator
from torchrl_dual.recipe.kits.minari_families import MINARI_KITS
from torchrl_dual.recipe.settings.errors import ConfigError, UserError
from torchrl_dual.recipe.settings.rules import (
    CellList,
    Choice,
    Either,
    IntegerList,
    Maybe,
    Real,
    key,
)
from torchrl_dual.transforms import PreviousTransition


# ----------------------------------------------------------------------------- PointMaze
@dataclass
class PointMazeSettings(EnvSettings):
    """``env/pointmaze_*.yaml``: Gymnasium-Robotics PointMaze, maze2d-style local data."""

    maze: str = key(Choice(tuple(POINTMAZE_IDS)), "layout")
    shift: str = key(Choice(shift_names("pointmaze")), "online-only dynamics shift")
    shift_angle: float = key(Real(-180, 180), "degrees of shift=rotation")
    shift_scale: Any = key(
        Maybe(Either((Real(0, 1000, low_open=True),), "must be a number in (0, 1000]")),
        "factor of shift=damping / mass (null: the shift's default)",
    )
    goal_cell: Any = key(
        Maybe(IntegerList(0)), "fixed goal cell [row, col] (null: a random open cell per episode)"
    )
    data_avoid_cells: Any = key(
        Maybe(CellList()), "open cells the offline data never enter (null: none)"
    )


def _check_pointmaze(cfg: DictConfig) -> None:
    """``env.goal_cell`` and every ``env.data_avoid_cells`` entry are open cells of
    ``env.maze`` (``[row, col]`` pairs)."""
    goal_cell = cfg.env.goal_cell
    if goal_cell is not None:
        try:
            goal_maze_map(cfg.env.maze, list(goal_cell))
        except ValueError as err:
            raise ConfigError("env.goal_cell", list(goal_cell), str(err)) from err
    for cell in _pointmaze_avoided(cfg.env) or ():
        try:
            goal_maze_map(cfg.env.maze, cell)
        except ValueError as err:
            raise ConfigError("env.data_avoid_cells", cell, str(err)) from err


def _pointmaze_shift(env: DictConfig) -> dict[str, Any]:
    return {"shift": env.shift, "shift_angle": env.shift_angle, "shift_scale": env.shift_scale}


def _pointmaze_goal(env: DictConfig) -> list[int] | None:
    return None if env.goal_cell is None else list(env.goal_cell)


def _pointmaze_avoided(env: DictConfig) -> list[list[int]] | None:
    cells = env.get("data_avoid_cells")
    return None if not cells else [list(cell) for cell in cells]


def _pointmaze_data(cfg: DictConfig) -> OfflineDataset:
    env = cfg.env
    return load_or_generate_maze_dataset(
        env.maze,
        cfg.budget.dataset_transitions,
        cfg.seed,
        cfg.data_cache_dir,
        max_episode_steps=env.max_episode_steps,
        goal_cell=_pointmaze_goal(env),
        avoid_cells=_pointmaze_avoided(env),
    )


def _pointmaze_env(cfg: DictConfig, data: OfflineDataset | None) -> EnvBase:
    env = cfg.env
    return make_pointmaze_env(
        env.maze,
        max_episode_steps=env.max_episode_steps,
        seed=cfg.seed,
        device="cpu",
        goal_cell=_pointmaze_goal(env),
        **_pointmaze_shift(env),
    )


def _pointmaze_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
    env = cfg.env

    def returns(policy: nn.Module, shift: dict[str, Any]) -> np.ndarray:
        return evaluate_episodes(
            lambda: make_pointmaze_gym_env(
                env.maze,
                max_episode_steps=env.max_episode_steps,
                goal_cell=_pointmaze_goal(env),
                **shift,
            ),
            policy,
            cfg.budget.eval_episodes,
            observation_fn=flatten_pointmaze_obs,
            action_fn=lambda a: np.clip(a, -1.0, 1.0),
            seed=10_000 + cfg.seed,
            device=cfg.device,
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        shifted = returns(policy, _pointmaze_shift(env))
        mean = float(shifted.mean())
        result = {
            "return": mean,
            "return_std": float(shifted.std()),
            "normalized_score": float(data.normalized_score(mean)),
        }
        if env.shift != "none":
            plain = float(returns(policy, {}).mean())
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = float(data.normalized_score(plain))
        return result

    return evaluate


# ----------------------------------------------------------------------------- Frozen-Lake
@dataclass
class FrozenLakeSettings(EnvSettings):
    """``env/frozenlake.yaml``: slippery Frozen-Lake with the paper's slip shift."""

    map_name: str = key(Choice(FROZENLAKE_MAPS), "map")
    offline_success_rate: float = key(Real(0, 1, low_open=True), "intended-move probability")
    online_success_rate: float = key(Real(0, 1, low_open=True), "intended-move probability")
    epsilon: float = key(Real(0, 1), "random-action probability of the behaviour policy")
    shift: str = key(Choice(shift_names("frozenlake")), "online-only dynamics shift")


def _frozenlake_data(cfg: DictConfig) -> OfflineDataset:
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


def _frozenlake_env(cfg: DictConfig, data: OfflineDataset | None) -> EnvBase:
    env = cfg.env
    return make_frozenlake_env(
        env.map_name,
        success_rate=env.online_success_rate,
        seed=cfg.seed,
        max_episode_steps=env.max_episode_steps,
        shift=env.shift,
    )


def _frozenlake_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
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
    """The executed discrete action as a one-hot vector (what the env receives)."""
    return nn.functional.one_hot(action.argmax(-1), action.shape[-1]).to(action.dtype)


# ----------------------------------------------------------------------------- the table
ENV_KITS: dict[str, EnvKit] = {
    "pointmaze": EnvKit(
        PointMazeSettings,
        _pointmaze_data,
        _pointmaze_env,
        _pointmaze_evaluator,
        check=_check_pointmaze,
    ),
    "frozenlake": EnvKit(
        FrozenLakeSettings,
        _frozenlake_data,
        _frozenlake_env,
        _frozenlake_evaluator,
        action_projection=one_hot_argmax,
    ),
    **MINARI_KITS,  # antmaze, locomotion, adroit (torchrl_dual.recipe.kits.minari_families)
}
"""``env.kind`` -> :class:`EnvKit`."""


def env_kit(cfg: DictConfig) -> EnvKit:
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
    return data


def projected_policy(cfg: DictConfig, policy: nn.Module) -> nn.Module:
    """``policy`` followed by the env kit's ``action_projection`` (the executed action the
    replay buffer stores, e.g. Frozen-Lake's one-hot argmax), or ``policy`` itself."""
    projection = env_kit(cfg).action_projection
    if projection is None:
        return policy
    return TensorDictSequential(
        policy, TensorDictModule(projection, in_keys=["action"], out_keys=["action"])
    )


def make_train_env(cfg: DictConfig, data: OfflineDataset | None = None) -> EnvBase:
    """The online env with :class:`PreviousTransition`, which carries ``(s_{t-1}, a_{t-1})``
    to the policy; the policy turns them into ``d_t`` of Eq. (10). ``data`` is
    ``D_offline`` when the caller has it (kits whose env depends on it read it otherwise)."""
    return env_kit(cfg).make_env(cfg, data).append_transform(PreviousTransition())


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
        >>> env.update(shift="none", shift_angle=0.0, shift_scale=None, goal_cell=None)
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
