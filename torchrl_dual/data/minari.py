"""Load Minari data sets (the D4RL successors) straight into the transition layout.

TorchRL 0.14.1's ``MinariExperienceReplay`` returns all-zero data (its preprocessing
replaces the filled TensorDict with ``memmap_like``), so episodes are read with the
``minari`` package directly.

Dict observations are flattened by concatenating entries in a fixed order:

* goal-conditioned mazes: ``observation`` then ``desired_goal`` for PointMaze (its
  ``observation`` already starts with the position, ``achieved_goal``), and
  ``achieved_goal``, ``observation``, ``desired_goal`` otherwise (AntMaze's
  ``observation`` excludes the torso position);
* other dict spaces: sorted keys.

The order used is recorded in ``metadata["observation_keys"]``. Discrete observations and
actions become one-hot float32 vectors (as in :func:`~torchrl_dual.envs.make_frozenlake_env`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from torchrl_dual.data.offline_dataset import OfflineDataset
from torchrl_dual.data.transition_layout import make_transitions


def default_observation_keys(keys: Sequence[str], env_id: str | None = None) -> list[str]:
    """Order in which the entries of a dict observation are concatenated.

    Args:
        keys (sequence of str): the dict observation's keys.
        env_id (str, optional): id of the env that produced the data.

    Examples:
        >>> keys = ["achieved_goal", "desired_goal", "observation"]
        >>> default_observation_keys(keys, "PointMaze_UMaze-v3")
        ['observation', 'desired_goal']
        >>> default_observation_keys(keys, "AntMaze_UMaze-v5")
        ['achieved_goal', 'observation', 'desired_goal']
    """
    keys = list(keys)
    if {"observation", "desired_goal"} <= set(keys):
        point_maze = env_id is not None and env_id.startswith("PointMaze")
        ordered = ["observation", "desired_goal"]
        if "achieved_goal" in keys and not point_maze:
            ordered.insert(0, "achieved_goal")
        return ordered
    return sorted(keys)


def _flatten(value: Any, keys: Sequence[str] | None, length: int) -> np.ndarray:
    if isinstance(value, dict):
        if keys is None:
            keys = sorted(value)
        missing = [k for k in keys if k not in value]
        if missing:
            raise ValueError(
                f"Observation entries {missing} not found; available: {sorted(value)}."
            )
        parts = [_flatten(value[k], None, length) for k in keys]
        return np.concatenate(parts, axis=-1)
    if isinstance(value, tuple):
        return np.concatenate([_flatten(v, None, length) for v in value], axis=-1)
    return np.asarray(value, dtype=np.float32).reshape(length, -1)


def _encode(values: Any, space: Any, keys: Sequence[str] | None, length: int) -> np.ndarray:
    """Flat float32 ``[length, dim]`` array; ``Discrete`` spaces become one-hot vectors."""
    import gymnasium as gym

    if isinstance(space, gym.spaces.Discrete):
        index = np.asarray(values, dtype=np.int64).reshape(length) - int(space.start)
        return np.eye(int(space.n), dtype=np.float32)[index]
    return _flatten(values, keys, length)


def _missing_message(dataset_id: str, path: Any) -> str:
    return (
        f"Minari dataset {dataset_id!r} is not available locally (looked in {path}). "
        f"Download it with:\n    minari download {dataset_id}\n"
        "or call load_minari_dataset(..., download=True). Set MINARI_DATASETS_PATH to "
        "use another datasets directory."
    )


def load_minari_dataset(
    dataset_id: str,
    *,
    download: bool = False,
    observation_keys: Sequence[str] | None = None,
) -> OfflineDataset:
    """Reads every episode of a Minari data set into the transition layout.

    Args:
        dataset_id (str): e.g. ``"D4RL/antmaze/umaze-v1"`` or ``"mujoco/hopper/medium-v0"``.

    Keyword Args:
        download (bool): download the data set if it is not in ``MINARI_DATASETS_PATH``
            (needs internet). Defaults to ``False``.
        observation_keys (sequence of str, optional): order of the dict-observation
            entries to concatenate; see :func:`default_observation_keys`.

    Returns:
        an :class:`OfflineDataset` whose ``reference_min`` / ``reference_max`` are the
        data set's ``ref_min_score`` / ``ref_max_score`` (``None`` when absent).

    Raises:
        FileNotFoundError: the data set is not local and ``download=False``; the message
            gives the exact ``minari download <id>`` command.
        ImportError: ``minari`` (or its storage backend) is not installed.

    Examples:
        >>> load_minari_dataset("D4RL/antmaze/umaze-v1")  # doctest: +SKIP
        OfflineDataset(transitions=TensorDict(...), reference_min=0.0, reference_max=1.0, ...)
    """
    try:
        import minari
        from minari.storage import get_dataset_path
    except ImportError as err:
        raise ImportError(
            "Loading Minari data sets needs the minari package: pip install 'minari[hdf5]'."
        ) from err
    path = get_dataset_path(dataset_id)
    if not download and not (path / "data").exists():
        raise FileNotFoundError(_missing_message(dataset_id, path))
    dataset = minari.load_dataset(dataset_id, download=download)
    env_spec = dataset.env_spec
    env_id = getattr(env_spec, "id", None)
    obs_space = dataset.observation_space
    keys: list[str] | None = None
    if hasattr(obs_space, "spaces") and isinstance(obs_space.spaces, dict):
        keys = list(observation_keys or default_observation_keys(list(obs_space.spaces), env_id))

    columns: dict[str, list[np.ndarray]] = {
        k: [] for k in ("obs", "act", "next", "rew", "term", "trunc", "ep")
    }
    for new_id, episode in enumerate(dataset.iterate_episodes()):
        length = len(episode)
        if length == 0:
            continue
        obs = _encode(episode.observations, obs_space, keys, length + 1)
        columns["obs"].append(obs[:-1])
        columns["next"].append(obs[1:])
        columns["act"].append(_encode(episode.actions, dataset.action_space, None, length))
        columns["rew"].append(np.asarray(episode.rewards, dtype=np.float32).reshape(length))
        columns["term"].append(np.asarray(episode.terminations, dtype=bool).reshape(length))
        columns["trunc"].append(np.asarray(episode.truncations, dtype=bool).reshape(length))
        columns["ep"].append(np.full(length, new_id, dtype=np.int64))
    if not columns["obs"]:
        raise ValueError(f"Minari dataset {dataset_id!r} has no transitions.")
    stacked = {k: np.concatenate(v) for k, v in columns.items()}
    td = make_transitions(
        stacked["obs"],
        stacked["act"],
        stacked["next"],
        stacked["rew"],
        stacked["term"],
        stacked["trunc"],
        stacked["ep"],
    )
    meta = dict(dataset.storage.metadata)
    ref_min, ref_max = meta.get("ref_min_score"), meta.get("ref_max_score")
    metadata = {
        "source": "minari",
        "dataset_id": dataset_id,
        "env_id": env_id,
        "observation_keys": keys,
        "num_episodes": len(columns["ep"]),
        "minari_version": str(meta.get("minari_version", "")),
    }
    return OfflineDataset(
        td,
        reference_min=None if ref_min is None else float(ref_min),
        reference_max=None if ref_max is None else float(ref_max),
        metadata=metadata,
    )
