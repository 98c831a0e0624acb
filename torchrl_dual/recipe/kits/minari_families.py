"""Env kits for the paper's benchmarks from Minari: AntMaze, MuJoCo locomotion, Adroit.

One :class:`MinariFamily` per kind names the published data sets
(``D4RL/antmaze/<dataset>-v1``, ``mujoco/<task>/<dataset>-v0``,
``D4RL/<task>/<dataset>-v2``); every family shares one data path, one env and one
evaluator:

* ``D_offline`` is read by :func:`~torchrl_dual.data.load_minari_dataset` (dict
  observations flattened in :func:`~torchrl_dual.data.default_observation_keys` order),
  then preprocessed as CORL does for IQL: rewards ``r' = reward_scale * r + reward_shift``
  (AntMaze ``r - 1``; locomotion ``reward_scale: returns`` = ``T / (max - min)`` of the
  data set's episode returns, ``T`` the time limit) and states normalized with the data
  set's mean and std + 1e-3 (:func:`observation_normalizer`).
* The online env and the evaluation env are the data set's own
  (``recover_environment()`` and ``recover_environment(eval_env=True)``: same id,
  version and kwargs as the data), under ``env.shift`` (online only), behind the same
  :class:`~torchrl_dual.envs.FlatObservation` map as the data; their observation space
  must match the data set's (:func:`check_observation_layout`).
* Scores are D4RL-normalized with the data set's ``ref_min_score`` / ``ref_max_score``
  (or ``env.reference_returns``); without references the evaluator says so
  (``normalized_score`` NaN and a ``score_note``) instead of inventing one.

A data set that is not on disk stops ``validate_config`` with the exact
``minari download <id>`` command (:func:`check_minari_dataset`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import OfflineDataset, load_minari_dataset
from torchrl_dual.envs import (
    FlatObservation,
    apply_shift,
    make_flat_env,
    register_robotics_envs,
    release_maze_xml,
    shift_names,
)
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.recipe.kits.kit import EnvKit, EnvSettings, Evaluator
from torchrl_dual.recipe.settings.errors import ConfigError, UserError
from torchrl_dual.recipe.settings.rules import (
    Choice,
    Either,
    Flag,
    Integer,
    Maybe,
    Real,
    RealList,
    Text,
    key,
)

OBSERVATION_STD_EPS = 1e-3
"""Added to the data set's state std (CORL's ``compute_mean_std(eps=1e-3)``)."""


@dataclass(frozen=True)
class MinariFamily:
    """Published Minari data sets of one env kind.

    Args:
        id_format (str): the data set id with ``{task}``, ``{dataset}``, ``{version}``.
        tasks (tuple of str): values of ``env.task`` (empty: the family has one task).
        datasets (tuple of str): known data set names (others are accepted: Minari grows).
    """

    id_format: str
    tasks: tuple[str, ...]
    datasets: tuple[str, ...]

    def dataset_id(self, env: DictConfig) -> str:
        """The Minari id of ``env.task`` / ``env.dataset`` / ``env.dataset_version``."""
        task = env.get("task", "")
        return self.id_format.format(task=task, dataset=env.dataset, version=env.dataset_version)


FAMILIES: dict[str, MinariFamily] = {
    "antmaze": MinariFamily(
        "D4RL/antmaze/{dataset}-{version}",
        (),
        ("umaze", "umaze-diverse", "medium-play", "medium-diverse", "large-play", "large-diverse"),
    ),
    "locomotion": MinariFamily(
        "mujoco/{task}/{dataset}-{version}",
        ("hopper", "halfcheetah", "walker2d"),
        ("medium", "expert", "simple"),
    ),
    "adroit": MinariFamily(
        "D4RL/{task}/{dataset}-{version}",
        ("pen", "door", "hammer", "relocate"),
        ("cloned", "human", "expert"),
    ),
}
"""``env.kind`` -> :class:`MinariFamily`."""


@dataclass
class MinariSettings(EnvSettings):
    """``env/antmaze.yaml``, ``env/hopper.yaml``, ...: a Minari data set and its env."""

    max_episode_steps: Any = key(
        Maybe(Integer(1)), "time limit; null: the data set's env spec (AntMaze 700/1000)"
    )
    dataset: str = key(Text(), "data set name, e.g. umaze, medium, cloned")
    dataset_version: str = key(Text(), "Minari version suffix, e.g. v1")
    reward_scale: Any = key(
        Either((Real(0, low_open=True), Choice(("returns",))), "must be a number > 0 or 'returns'"),
        "r' = reward_scale * r + reward_shift; returns: T / (max - min episode return)",
    )
    reward_shift: float = key(Real(), "added after the scale (CORL AntMaze: -1)")
    normalize_observations: bool = key(Flag(), "states -> (s - mean) / (std + 1e-3) of the data")
    reference_returns: Any = key(
        Maybe(RealList(2)), "[random, expert] returns instead of the data set's references"
    )
    shift_scale: Any = key(
        Maybe(Real(0, low_open=True)), "factor of the shift (null: the shift's default)"
    )


@dataclass
class AntMazeSettings(MinariSettings):
    """``env/antmaze.yaml``: Minari ``D4RL/antmaze/<dataset>-<version>``."""

    shift: str = key(Choice(shift_names("antmaze")), "online-only dynamics shift")


@dataclass
class LocomotionSettings(MinariSettings):
    """``env/hopper.yaml``, ``halfcheetah.yaml``, ``walker2d.yaml``: Minari
    ``mujoco/<task>/<dataset>-<version>`` and the ODRL shifts."""

    task: str = key(Choice(FAMILIES["locomotion"].tasks), "the robot")
    shift: str = key(Choice(shift_names("locomotion")), "online-only dynamics shift (ODRL)")


@dataclass
class AdroitSettings(MinariSettings):
    """``env/adroit.yaml``: Minari ``D4RL/<task>/<dataset>-<version>``."""

    task: str = key(Choice(FAMILIES["adroit"].tasks), "the Adroit hand task")
    shift: str = key(Choice(shift_names("adroit")), "online-only dynamics shift")


SETTINGS: dict[str, type] = {
    "antmaze": AntMazeSettings,
    "locomotion": LocomotionSettings,
    "adroit": AdroitSettings,
}


# ----------------------------------------------------------------------------- checks
def check_minari_dataset(cfg: DictConfig) -> None:
    """Stops before any work when minari is missing or the data set is not on disk."""
    dataset_id = FAMILIES[cfg.env.kind].dataset_id(cfg.env)
    try:
        from minari.storage import get_dataset_path
    except ImportError as err:
        raise ConfigError(
            "env.kind",
            cfg.env.kind,
            "reading Minari data sets needs the minari package: pip install 'torchrl-dual[minari]'",
        ) from err
    path = get_dataset_path(dataset_id)
    if not (path / "data").exists():
        raise ConfigError(
            "env.dataset",
            cfg.env.dataset,
            f"the Minari data set {dataset_id} is not on disk (looked in {path}; set "
            f"MINARI_DATASETS_PATH to look elsewhere); download it with: "
            f"minari download {dataset_id}",
        )


def check_observation_layout(dataset_space: Any, env_space: Any, dataset_id: str) -> None:
    """Raises :class:`UserError` unless the env's observations have the data set's layout
    (same dict entries with the same shapes, or the same array shape).

    Examples:
        >>> import gymnasium as gym
        >>> box = gym.spaces.Box(-1, 1, (3,))
        >>> check_observation_layout(gym.spaces.Dict({"a": box}), gym.spaces.Dict({"a": box}), "x")
    """

    def layout(space: Any) -> Any:
        if hasattr(space, "spaces") and isinstance(space.spaces, dict):
            return {k: tuple(v.shape) for k, v in space.spaces.items()}
        return tuple(space.shape)

    if layout(dataset_space) != layout(env_space):
        raise UserError(
            "env.dataset",
            dataset_id,
            f"the data set's observations {layout(dataset_space)} differ from its env's "
            f"{layout(env_space)}: the installed Gymnasium-Robotics / MuJoCo env version does "
            "not produce the data's layout; install the versions the data set lists "
            "(minari show <id>) or use a data set made with this env",
        )


# ----------------------------------------------------------------------------- data
def _episode_returns(data: OfflineDataset) -> torch.Tensor:
    td = data.transitions
    episodes = td["episode"]
    _, index = torch.unique(episodes, return_inverse=True)
    returns = torch.zeros(int(index.max()) + 1, dtype=torch.float64)
    return returns.index_add_(0, index, td["next", "reward"].squeeze(-1).double())


def observation_normalizer(data: OfflineDataset, enabled: bool) -> tuple[np.ndarray, np.ndarray]:
    """``(loc, scale)`` of the state normalization: the data set's mean and std + 1e-3
    over its observations, or ``(0, 1)`` when disabled."""
    obs = data.transitions["observation"].double()
    if not enabled:
        return np.zeros(obs.shape[-1], np.float32), np.ones(obs.shape[-1], np.float32)
    loc = obs.mean(0)
    scale = obs.std(0, unbiased=False) + OBSERVATION_STD_EPS
    return loc.float().numpy(), scale.float().numpy()


def _time_limit(cfg: DictConfig, dataset_id: str) -> int | None:
    if cfg.env.max_episode_steps is not None:
        return int(cfg.env.max_episode_steps)
    import minari

    spec = minari.load_dataset(dataset_id).env_spec
    return None if spec is None else spec.max_episode_steps


def _minari_data(cfg: DictConfig) -> OfflineDataset:
    env = cfg.env
    dataset_id = FAMILIES[env.kind].dataset_id(env)
    data = load_minari_dataset(dataset_id)
    td = data.transitions
    if env.reward_scale == "returns":
        returns = _episode_returns(data)
        spread = float(returns.max() - returns.min())
        horizon = _time_limit(cfg, dataset_id) or 1000
        if spread <= 0:
            raise UserError(
                "env.reward_scale",
                "returns",
                f"every episode of {dataset_id} has the same return; set a number instead",
            )
        reward_scale = horizon / spread
    else:
        reward_scale = float(env.reward_scale)
    td["next", "reward"] = td["next", "reward"] * reward_scale + float(env.reward_shift)
    loc, scale = observation_normalizer(data, env.normalize_observations)
    loc_t, scale_t = torch.as_tensor(loc), torch.as_tensor(scale)
    td["observation"] = (td["observation"] - loc_t) / scale_t
    td["next", "observation"] = (td["next", "observation"] - loc_t) / scale_t
    if env.reference_returns is not None:
        data.reference_min, data.reference_max = (float(v) for v in env.reference_returns)
    data.metadata.update(
        reward_scale=reward_scale,
        reward_shift=float(env.reward_shift),
        observation_loc=loc.tolist(),
        observation_scale=scale.tolist(),
    )
    return data


# ----------------------------------------------------------------------------- envs
def _gym_env(cfg: DictConfig, data: OfflineDataset, *, eval_env: bool, shifted: bool):
    """The data set's (evaluation) env, shifted if asked, behind the data's observation map."""
    import minari

    env = cfg.env
    dataset_id = FAMILIES[env.kind].dataset_id(env)
    dataset = minari.load_dataset(dataset_id)
    register_robotics_envs()  # AntMaze / Adroit ids, without the import's notice
    kwargs = {} if env.max_episode_steps is None else {"max_episode_steps": env.max_episode_steps}
    raw = release_maze_xml(dataset.recover_environment(eval_env=eval_env, **kwargs))
    check_observation_layout(dataset.observation_space, raw.observation_space, dataset_id)
    if shifted:
        raw = apply_shift(raw, env.shift, scale=env.shift_scale, kind=env.kind)
    meta = data.metadata
    return FlatObservation(
        raw,
        keys=meta.get("observation_keys"),
        loc=np.asarray(meta["observation_loc"], np.float32),
        scale=np.asarray(meta["observation_scale"], np.float32),
    )


def _minari_env(cfg: DictConfig, data: OfflineDataset | None) -> EnvBase:
    if data is None:  # its observation normalization and reward scale come from the data
        data = _minari_data(cfg)
    return make_flat_env(
        _gym_env(cfg, data, eval_env=False, shifted=True),
        reward_scale=data.metadata["reward_scale"],
        reward_shift=data.metadata["reward_shift"],
        seed=cfg.seed,
    )


def _minari_evaluator(cfg: DictConfig, data: OfflineDataset) -> Evaluator:
    """Deterministic episodes in the data set's evaluation env; raw (unmodified) returns."""
    has_references = data.reference_min is not None and data.reference_max is not None

    def score(mean_return: float) -> float:
        return float(data.normalized_score(mean_return)) if has_references else math.nan

    def returns(policy: nn.Module, shifted: bool) -> np.ndarray:
        probe = _gym_env(cfg, data, eval_env=True, shifted=False)
        low, high = probe.action_space.low, probe.action_space.high
        probe.close()
        return evaluate_episodes(
            lambda: _gym_env(cfg, data, eval_env=True, shifted=shifted),
            policy,
            cfg.budget.eval_episodes,
            observation_fn=lambda obs: obs,
            action_fn=lambda a: np.clip(a, low, high),
            seed=10_000 + cfg.seed,
            device=cfg.device,
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        shifted = returns(policy, cfg.env.shift != "none")
        mean = float(shifted.mean())
        result: dict[str, Any] = {
            "return": mean,
            "return_std": float(shifted.std()),
            "normalized_score": score(mean),
        }
        if cfg.env.shift != "none":
            plain = float(returns(policy, False).mean())
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = score(plain)
        return result

    return evaluate


MINARI_KITS: dict[str, EnvKit] = {
    kind: EnvKit(
        SETTINGS[kind], _minari_data, _minari_env, _minari_evaluator, check=check_minari_dataset
    )
    for kind in FAMILIES
}
"""The Minari kinds of :data:`~torchrl_dual.recipe.kits.build.ENV_KITS`."""
