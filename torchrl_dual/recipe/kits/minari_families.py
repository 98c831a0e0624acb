"""Env kits for the paper's benchmarks from Minari: AntMaze, MuJoCo locomotion, Adroit.

One :class:`MinariFamily` per kind names the published data sets
(``D4RL/antmaze/<dataset>-v1``, ``mujoco/<task>/<dataset>-v0``,
``D4RL/<task>/<dataset>-v2``); every family shares one data path, one env and one
evaluator:

What D4RL's protocol changes (``env.protocol=d4rl``, the default: AntMaze's single-goal
task, D4RL's horizons and references) comes from :mod:`~torchrl_dual.recipe.kits.d4rl_protocol`.

* ``D_offline`` is read by :func:`~torchrl_dual.data.load_minari_dataset` (dict
  observations flattened in :func:`~torchrl_dual.data.default_observation_keys` order, or
  the protocol's: AntMaze without ``desired_goal``), AntMaze's rewards and terminals
  relabelled to D4RL's goal (:func:`~torchrl_dual.data.relabel_to_goal`), then
  preprocessed as the critic's reference does: rewards ``r' = reward_scale * r +
  reward_shift`` (:func:`~torchrl_dual.recipe.settings.references.reward_transform`: IQL's AntMaze
  ``r - 1``, Cal-QL's ``10 r - 5``; locomotion ``returns`` = ``T / (max - min)`` of the
  data set's episode returns, ``T`` the time limit) and states normalized with the data
  set's mean and std + 1e-3 (:func:`observation_normalizer`).
* The online env and the evaluation env are the data set's own
  (``recover_environment()``; under ``protocol=minari`` the evaluation uses
  ``recover_environment(eval_env=True)``: same id, version and kwargs as the data), at the
  protocol's time limit, AntMaze wrapped in :class:`~torchrl_dual.envs.SingleGoalAntMaze`
  and Pen in :class:`~torchrl_dual.envs.PenDropTermination` under ``d4rl``, under
  ``env.shift`` (online only), behind the same :class:`~torchrl_dual.envs.FlatObservation`
  map as the data; their observation space
  must match the data set's (:func:`check_observation_layout`).
* Scores are D4RL-normalized with the protocol's references (``d4rl``: D4RL's; ``minari``:
  the data set's ``ref_min_score`` / ``ref_max_score``) or ``env.reference_returns``;
  without references the evaluator says so (``normalized_score`` NaN and a
  ``score_note``) instead of inventing one.

A data set that is not on disk stops ``validate_config`` with the exact
``minari download <id>`` command (:func:`check_minari_dataset`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import OfflineDataset, load_minari_dataset
from torchrl_dual.data.goal_relabel import relabel_to_goal
from torchrl_dual.envs import (
    FlatObservation,
    PenDropTermination,
    apply_shift,
    make_flat_env,
    register_robotics_envs,
    release_maze_xml,
)
from torchrl_dual.envs.d4rl_antmaze import D4RL_SUCCESS_RADIUS, SingleGoalAntMaze
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.recipe.kits.build import Evaluator
from torchrl_dual.recipe.kits.d4rl_protocol import (
    data_protocol,
    horizon_of_seconds,
    protocol_metadata,
)
from torchrl_dual.recipe.settings.errors import UserError
from torchrl_dual.recipe.settings.minari_datasets import FAMILIES
from torchrl_dual.recipe.settings.references import reward_transform
from torchrl_dual.recipe.settings.structured import RecipeSettings

OBSERVATION_STD_EPS = 1e-3
"""Added to the data set's state std (CORL's ``compute_mean_std(eps=1e-3)``)."""


def check_observation_layout(dataset_space: Any, env_space: Any, dataset_id: str) -> None:
    """Raises :class:`UserError` unless the env's observations have the data set's layout.

    The same dict entries with the same shapes, or the same array shape.

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
    """``(loc, scale)`` of the state normalization, or ``(0, 1)`` when disabled.

    The data set's mean and std + 1e-3 over its observations.
    """
    obs = data.transitions["observation"].double()
    if not enabled:
        return np.zeros(obs.shape[-1], np.float32), np.ones(obs.shape[-1], np.float32)
    loc = obs.mean(0)
    scale = obs.std(0, unbiased=False) + OBSERVATION_STD_EPS
    return loc.float().numpy(), scale.float().numpy()


def _time_limit(settings: RecipeSettings, dataset_id: str) -> int | None:
    """The episodes' time limit of a Minari run.

    ``env.max_episode_steps``, else AntMaze's ``env.horizon_seconds``, else the
    protocol's, else the data set's env spec.
    """
    if settings.env.max_episode_steps is not None:
        return int(settings.env.max_episode_steps)
    steps = horizon_of_seconds(settings.env)
    if steps is not None:
        return steps
    protocol = data_protocol(settings.env)
    if protocol.max_episode_steps is not None:
        return protocol.max_episode_steps
    import minari

    spec = minari.load_dataset(dataset_id).env_spec
    return None if spec is None else spec.max_episode_steps


def minari_data(settings: RecipeSettings) -> OfflineDataset:
    """A Minari family's ``D_offline``, following ``env.protocol``.

    The data set's transitions (D4RL's single goal relabelled for AntMaze), the references of
    the protocol, and the reward transform (:func:`reward_transform`) applied and recorded in
    the metadata.
    """
    env = settings.env
    dataset_id = FAMILIES[env.kind].dataset_id(env)
    protocol = data_protocol(settings.env)
    data = load_minari_dataset(dataset_id, observation_keys=protocol.observation_keys)
    if protocol.antmaze_task is not None:  # D4RL's single goal: its rewards and terminals
        data.transitions = relabel_to_goal(
            data.transitions, protocol.antmaze_task.goal, radius=D4RL_SUCCESS_RADIUS
        )
    if protocol.references is not None:
        data.reference_min, data.reference_max = protocol.references
    td = data.transitions
    reward_scale_setting, reward_shift = reward_transform(settings.env, settings.critic.name)
    if reward_scale_setting == "returns":
        returns = _episode_returns(data)
        spread = float(returns.max() - returns.min())
        horizon = _time_limit(settings, dataset_id) or 1000
        if spread <= 0:
            raise UserError(
                "env.reward_scale",
                "returns",
                f"every episode of {dataset_id} has the same return; set a number instead",
            )
        reward_scale = horizon / spread
    else:
        reward_scale = float(reward_scale_setting)
    td["next", "reward"] = td["next", "reward"] * reward_scale + reward_shift
    loc, scale = observation_normalizer(data, env.normalize_observations)
    loc_t, scale_t = torch.as_tensor(loc), torch.as_tensor(scale)
    td["observation"] = (td["observation"] - loc_t) / scale_t
    td["next", "observation"] = (td["next", "observation"] - loc_t) / scale_t
    if env.reference_returns is not None:
        data.reference_min, data.reference_max = (float(v) for v in env.reference_returns)
    data.metadata.update(
        **protocol_metadata(protocol),
        reward_scale=reward_scale,
        reward_shift=reward_shift,
        observation_loc=loc.tolist(),
        observation_scale=scale.tolist(),
    )
    return data


# ----------------------------------------------------------------------------- envs
def minari_gym_env(
    settings: RecipeSettings, data: OfflineDataset, *, eval_env: bool, shifted: bool
):
    """The data set's (evaluation) env, shifted if asked, behind the data's observation map."""
    import minari

    env = settings.env
    dataset_id = FAMILIES[env.kind].dataset_id(env)
    dataset = minari.load_dataset(dataset_id)
    register_robotics_envs()  # AntMaze / Adroit ids, without the import's notice
    protocol = data_protocol(settings.env)
    horizon = _time_limit(settings, dataset_id)
    kwargs = {} if horizon is None else {"max_episode_steps": horizon}
    eval_env = eval_env and protocol.evaluate_in_eval_env
    raw = release_maze_xml(dataset.recover_environment(eval_env=eval_env, **kwargs))
    check_observation_layout(dataset.observation_space, raw.observation_space, dataset_id)
    if protocol.antmaze_task is not None:
        raw = SingleGoalAntMaze(raw, protocol.antmaze_task, goal_noise=env.goal_noise)
    if protocol.pen_drop_ends:
        raw = PenDropTermination(raw)
    if shifted:
        raw = apply_shift(raw, env.shift, scale=env.shift_scale, kind=env.kind)
    meta = data.metadata
    return FlatObservation(
        raw,
        keys=meta.get("observation_keys"),
        loc=np.asarray(meta["observation_loc"], np.float32),
        scale=np.asarray(meta["observation_scale"], np.float32),
    )


def minari_env(settings: RecipeSettings, data: OfflineDataset | None) -> EnvBase:
    """A Minari family's online env: flat, normalized observations, the data's reward transform."""
    if data is None:  # its observation normalization and reward scale come from the data
        data = minari_data(settings)
    return make_flat_env(
        minari_gym_env(settings, data, eval_env=False, shifted=True),
        reward_scale=data.metadata["reward_scale"],
        reward_shift=data.metadata["reward_shift"],
        seed=settings.seed,
    )


def minari_evaluator(settings: RecipeSettings, data: OfflineDataset) -> Evaluator:
    """Deterministic episodes in the data set's evaluation env; raw (unmodified) returns.

    The envs are built at the first evaluation and kept.
    """
    has_references = data.reference_min is not None and data.reference_max is not None
    kept: dict[bool, list] = {True: [], False: []}  # shifted, unshifted
    probe = minari_gym_env(settings, data, eval_env=True, shifted=False)
    low, high = probe.action_space.low, probe.action_space.high
    probe.close()

    def score(mean_return: float) -> float:
        return float(data.normalized_score(mean_return)) if has_references else math.nan

    def returns(policy: nn.Module, shifted: bool) -> np.ndarray:
        return evaluate_episodes(
            lambda: minari_gym_env(settings, data, eval_env=True, shifted=shifted),
            policy,
            settings.budget.eval_episodes,
            observation_fn=lambda obs: obs,
            action_fn=lambda a: np.clip(a, low, high),
            seed=10_000 + settings.seed,
            device=settings.device,
            envs=kept[shifted],
        )

    def evaluate(policy: nn.Module) -> dict[str, float]:
        shifted = returns(policy, settings.env.shift != "none")
        mean = float(shifted.mean())
        result: dict[str, Any] = {
            "return": mean,
            "return_std": float(shifted.std()),
            "normalized_score": score(mean),
        }
        if settings.env.shift != "none":
            plain = float(returns(policy, False).mean())
            result["return_unshifted"] = plain
            result["normalized_score_unshifted"] = score(plain)
        return result

    return evaluate
