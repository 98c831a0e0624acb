"""Epsilon-greedy offline data for slippery Frozen-Lake (the paper's slip-shift task).

The greedy policy is optimal (discounted value iteration, ``gamma=0.99``) for the
*offline* slip (``success_rate=3/4``); with probability ``epsilon`` a uniformly random
action is taken instead. Observations are one-hot float32 cells and actions one-hot
float32 vectors of the intended move, as produced by
:func:`~torchrl_dual.envs.make_frozenlake_env`.

Score references are exact success probabilities within the 100-step limit, computed by
value iteration in the *evaluation* env (``eval_success_rate``, 2/3 by default: the
online phase): ``reference_min`` for the uniformly random policy, ``reference_max`` for
the policy optimal there.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from torchrl_dual.data.cache import default_cache_dir, load_or_generate
from torchrl_dual.data.offline_dataset import OfflineDataset
from torchrl_dual.data.transition_layout import make_transitions
from torchrl_dual.envs.frozenlake import FROZENLAKE_NUM_ACTIONS, frozenlake_num_states
from torchrl_dual.envs.frozenlake_mdp import (
    FROZENLAKE_HORIZON,
    frozenlake_optimal_policy,
    frozenlake_success_probability,
    frozenlake_value_iteration,
)

FROZENLAKE_GENERATOR_VERSION = 1


def generate_frozenlake_dataset(
    map_name: str = "4x4",
    num_transitions: int = 20_000,
    *,
    seed: int = 0,
    success_rate: float = 3 / 4,
    epsilon: float = 0.3,
    eval_success_rate: float = 2 / 3,
    gamma: float = 0.99,
    max_episode_steps: int = FROZENLAKE_HORIZON,
) -> OfflineDataset:
    """Collects epsilon-greedy transitions in slippery ``FrozenLake-v1``.

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        num_transitions (int): number of transitions (the last episode is cut and marked
            ``truncated`` if needed).

    Keyword Args:
        seed (int): seeds the env and the behaviour policy.
        success_rate (float): slip setting of the data-collection env. Defaults to 3/4.
        epsilon (float): probability of a uniformly random action. Defaults to 0.3.
        eval_success_rate (float): slip setting of the env scores are reported on.
        gamma (float): discount used to pick the greedy (optimal) policy.
        max_episode_steps (int): time limit. Defaults to 100.

    Examples:
        >>> data = generate_frozenlake_dataset("4x4", 1000, seed=0)
        >>> len(data), data.obs_dim, data.action_dim
        (1000, 16, 4)
        >>> round(data.reference_min, 4), round(data.reference_max, 4)
        (0.0139, 0.7082)
    """
    if num_transitions <= 0:
        raise ValueError(f"num_transitions must be positive, got {num_transitions}.")
    if not 0.0 <= epsilon <= 1.0:
        raise ValueError(f"epsilon must be in [0, 1], got {epsilon}.")
    n_states = frozenlake_num_states(map_name)
    greedy = frozenlake_optimal_policy(map_name, success_rate, gamma=gamma)
    env = gym.make(
        "FrozenLake-v1",
        map_name=map_name,
        is_slippery=True,
        success_rate=float(success_rate),
        max_episode_steps=int(max_episode_steps),
    )
    rng = np.random.default_rng([seed, 2])
    explore = rng.random(num_transitions) < epsilon
    random_actions = rng.integers(FROZENLAKE_NUM_ACTIONS, size=num_transitions)

    n = num_transitions
    states = np.empty(n, np.int64)
    next_states = np.empty(n, np.int64)
    actions = np.empty(n, np.int64)
    rewards = np.empty(n, np.float32)
    term = np.zeros(n, bool)
    trunc = np.zeros(n, bool)
    episodes = np.empty(n, np.int64)
    episode = 0
    state, _ = env.reset(seed=int(seed))
    for t in range(n):
        action = int(random_actions[t]) if explore[t] else int(greedy[state])
        next_state, reward, terminated, truncated, _ = env.step(action)
        states[t], actions[t], next_states[t] = state, action, next_state
        rewards[t], term[t], episodes[t] = reward, terminated, episode
        trunc[t] = truncated or (t == n - 1 and not terminated)
        state = next_state
        if terminated or truncated:
            episode += 1
            state, _ = env.reset()
    env.close()

    eye_s = np.eye(n_states, dtype=np.float32)
    eye_a = np.eye(FROZENLAKE_NUM_ACTIONS, dtype=np.float32)
    td = make_transitions(
        eye_s[states], eye_a[actions], eye_s[next_states], rewards, term, trunc, episodes
    )
    behaviour = (1 - epsilon) * eye_a[greedy].astype(np.float64) + epsilon / FROZENLAKE_NUM_ACTIONS
    evaluation = frozenlake_value_iteration(
        map_name, eval_success_rate, policy=greedy, gamma=gamma, horizon=max_episode_steps
    )
    offline = frozenlake_value_iteration(
        map_name, success_rate, gamma=gamma, horizon=max_episode_steps
    )

    def success(policy: np.ndarray, rate: float) -> float:
        return float(
            frozenlake_success_probability(policy, map_name, rate, horizon=max_episode_steps)
        )

    metadata: dict[str, Any] = {
        "source": "frozenlake_local",
        "map_name": map_name,
        "seed": int(seed),
        "num_transitions": int(n),
        "success_rate": float(success_rate),
        "eval_success_rate": float(eval_success_rate),
        "epsilon": float(epsilon),
        "gamma": float(gamma),
        "max_episode_steps": int(max_episode_steps),
        "generator_version": FROZENLAKE_GENERATOR_VERSION,
        "greedy_policy": greedy.tolist(),
        "references": {
            "random_success": evaluation.random_success,
            "optimal_success": evaluation.optimal_success,
            "greedy_success_eval": evaluation.policy_success,
            "greedy_success_offline": offline.optimal_success,
            "behaviour_success_offline": success(behaviour, success_rate),
            "behaviour_success_eval": success(behaviour, eval_success_rate),
            "finite_horizon_optimum_eval": evaluation.finite_horizon_optimum,
        },
        "data_success_fraction": float(rewards.sum() / max(episode, 1)),
    }
    return OfflineDataset(
        td,
        reference_min=evaluation.random_success,
        reference_max=evaluation.optimal_success,
        metadata=metadata,
    )


def load_or_generate_frozenlake_dataset(
    map_name: str = "4x4",
    num_transitions: int = 20_000,
    seed: int = 0,
    cache_dir: str | Path | None = None,
    **kwargs: Any,
) -> OfflineDataset:
    """Cached :func:`generate_frozenlake_dataset` (see :func:`torchrl_dual.data.load_or_generate`).

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        num_transitions (int): number of transitions.
        seed (int): seeds the env and the behaviour policy.
        cache_dir (str or Path, optional): the cache's root; defaults to
            :func:`~torchrl_dual.data.default_cache_dir`.
        **kwargs: the keyword arguments of :func:`generate_frozenlake_dataset`
            (``success_rate``, ``epsilon``, ``eval_success_rate``, ``gamma``,
            ``max_episode_steps``), part of the cache entry's identity.

    Returns:
        OfflineDataset: the cached data set, generated on a cache miss.

    Raises:
        ValueError: an unknown ``map_name``.

    Examples:
        >>> import tempfile
        >>> data = load_or_generate_frozenlake_dataset("4x4", 500, 0, tempfile.mkdtemp())
        >>> data.metadata["map_name"], len(data)
        ('4x4', 500)
    """
    frozenlake_num_states(map_name)  # fail fast on an unknown map
    root = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    spec = {
        "generator": "frozenlake_local",
        "generator_version": FROZENLAKE_GENERATOR_VERSION,
        "map_name": map_name,
        "num_transitions": int(num_transitions),
        "seed": int(seed),
        **kwargs,
    }
    path = root / f"frozenlake-{map_name}-n{num_transitions}-seed{seed}"
    return load_or_generate(
        path,
        spec,
        lambda: generate_frozenlake_dataset(map_name, num_transitions, seed=seed, **kwargs),
    )
