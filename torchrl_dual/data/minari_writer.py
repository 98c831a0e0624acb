"""Write Minari data sets from rollouts: the reverse of :mod:`torchrl_dual.data.minari`.

Published data sets (``D4RL/antmaze/umaze-v1``, ``mujoco/hopper/medium-v0``, ...) cannot be
downloaded everywhere (CI machines, air-gapped clusters), yet the code that reads them must
be exercised on real files. :func:`collect_episodes` rolls a policy out in a Gymnasium env
and returns whole-episode ``EpisodeBuffer`` objects; :func:`write_minari_dataset` stores
them with ``minari.create_dataset_from_buffers`` (no ``DataCollector``, so no jax) under
any id, with the env spec, evaluation env spec and reference returns a published data set
carries. :func:`load_minari_dataset` then reads them back like the published ones.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from typing import Any

import gymnasium as gym
import numpy as np


def _stack(values: list[Any]) -> Any:
    if isinstance(values[0], dict):
        return {k: _stack([v[k] for v in values]) for k in values[0]}
    return np.stack([np.asarray(v) for v in values])


def collect_episodes(
    env: gym.Env,
    policy: Callable[[Any], Any] | None,
    num_episodes: int,
    *,
    seed: int = 0,
    max_steps: int | None = None,
) -> list:
    """Rolls ``policy`` out for ``num_episodes`` whole episodes of ``env``.

    Args:
        env (gym.Env): the Gymnasium env (dict observations are kept as dicts).
        policy (callable or None): ``observation -> action``; ``None`` samples uniform
            random actions from ``env.action_space`` (seeded).
        num_episodes (int): episodes to collect.

    Keyword Args:
        seed (int): episode ``k`` is reset with ``seed + k``. Defaults to 0.
        max_steps (int, optional): cut an episode after this many steps (marked truncated),
            on top of the env's own time limit.

    Returns:
        a list of ``minari.data_collector.EpisodeBuffer``, one per episode, with
        ``observations`` holding ``T + 1`` entries for ``T`` actions.

    Examples:
        >>> env = gym.make("Pendulum-v1", max_episode_steps=5)
        >>> buffers = collect_episodes(env, None, 2)
        >>> [len(b.actions) for b in buffers], buffers[0].observations.shape
        ([5, 5], (6, 3))
    """
    from minari.data_collector import EpisodeBuffer

    if num_episodes < 1:
        raise ValueError(f"num_episodes must be >= 1, got {num_episodes}.")
    env.action_space.seed(seed)
    buffers = []
    for episode in range(num_episodes):
        obs, _ = env.reset(seed=seed + episode)
        steps: dict[str, list] = {"obs": [obs], "act": [], "rew": [], "term": [], "trunc": []}
        while True:
            action = env.action_space.sample() if policy is None else policy(obs)
            obs, reward, terminated, truncated, _ = env.step(action)
            if max_steps is not None and len(steps["act"]) + 1 >= max_steps:
                truncated = True
            for key, value in zip(
                ("obs", "act", "rew", "term", "trunc"),
                (obs, action, reward, terminated, truncated),
                strict=True,
            ):
                steps[key].append(value)
            if terminated or truncated:
                break
        buffers.append(
            EpisodeBuffer(
                id=episode,
                observations=_stack(steps["obs"]),
                actions=_stack(steps["act"]),
                rewards=np.asarray(steps["rew"], dtype=np.float64),
                terminations=np.asarray(steps["term"], dtype=bool),
                truncations=np.asarray(steps["trunc"], dtype=bool),
                infos={},
            )
        )
    return buffers


def write_minari_dataset(
    dataset_id: str,
    buffers: Sequence,
    env_spec: gym.envs.registration.EnvSpec,
    *,
    eval_env_spec: gym.envs.registration.EnvSpec | None = None,
    reference_returns: tuple[float, float] | None = None,
    algorithm_name: str = "torchrl_dual.data.minari_writer",
    description: str | None = None,
):
    """Stores episode buffers as the Minari data set ``dataset_id``.

    It is written in ``MINARI_DATASETS_PATH`` (``~/.minari/datasets`` by default).

    Args:
        dataset_id (str): e.g. ``"D4RL/antmaze/umaze-v1"`` (``namespace/name-vN``).
        buffers (sequence of EpisodeBuffer): whole episodes, e.g. from :func:`collect_episodes`.
        env_spec (EnvSpec): the spec ``recover_environment()`` rebuilds the env from (id,
            kwargs, time limit), e.g. ``env.spec`` of the env the episodes come from.

    Keyword Args:
        eval_env_spec (EnvSpec, optional): the evaluation env's spec
            (``recover_environment(eval_env=True)``); ``env_spec`` if omitted.
        reference_returns (tuple of float, optional): ``(ref_min_score, ref_max_score)``
            written to the metadata (the references of normalized scores); none if omitted.
        algorithm_name (str): the metadata's ``algorithm_name``.
        description (str, optional): the metadata's ``description``.

    Returns:
        the ``minari.MinariDataset``.

    Examples:
        >>> import os, tempfile
        >>> os.environ["MINARI_DATASETS_PATH"] = tempfile.mkdtemp()
        >>> env = gym.make("Pendulum-v1", max_episode_steps=5)
        >>> dataset = write_minari_dataset(
        ...     "demo/pendulum/random-v0", collect_episodes(env, None, 3), env.spec,
        ...     reference_returns=(-1500.0, -150.0))
        >>> dataset.total_episodes, dataset.storage.metadata["ref_max_score"]
        (3, -150.0)
    """
    import minari

    if not buffers:
        raise ValueError("write_minari_dataset needs at least one episode buffer.")
    kwargs: dict[str, Any] = {}
    if reference_returns is not None:
        ref_min, ref_max = (float(v) for v in reference_returns)
        kwargs.update(ref_min_score=ref_min, ref_max_score=ref_max)
    with warnings.catch_warnings():  # minari warns about missing optional metadata
        warnings.simplefilter("ignore")
        return minari.create_dataset_from_buffers(
            dataset_id,
            list(buffers),
            env=env_spec,
            eval_env=eval_env_spec if eval_env_spec is not None else env_spec,
            algorithm_name=algorithm_name,
            description=description,
            **kwargs,
        )
