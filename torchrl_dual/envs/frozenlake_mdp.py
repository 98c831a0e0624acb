"""Exact Frozen-Lake dynamics and value iteration (success probabilities within a horizon).

Frozen-Lake's transition matrix is known, so the success probability of any stationary
deterministic policy within the 100-step time limit is computed exactly by ``horizon``
rounds of policy evaluation. The "optimal policy" is the greedy policy of discounted
value iteration (``gamma=0.99`` by default): a stationary policy, the kind a state-only
actor can represent. With ``gamma=0.99`` on ``4x4`` the policy optimal at success_rate
3/4 succeeds 0.6915 under 2/3, where the optimal one succeeds 0.7082 (the figures of the
paper's slip shift). The best *time-dependent* policy for the 100-step criterion does
better (0.839 under 2/3); it is reported as ``finite_horizon_optimum``.

Every function takes ``shift`` (``"none"`` or ``"biased_slip"``, see
:mod:`~torchrl_dual.envs.shifts`): the model is built from the env's own transition table
after the shift rewrote it, so the exact figures and the env cannot disagree.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from torchrl_dual.envs.shifts import apply_shift, check_shift

FROZENLAKE_HORIZON = 100
"""Time limit of ``FrozenLake-v1`` (also for ``map_name="8x8"``)."""


@dataclass(frozen=True)
class FrozenLakeMDP:
    """Tabular Frozen-Lake model.

    Attributes:
        transitions (np.ndarray): ``P[s, a, s']``, shape ``[S, 4, S]``.
        rewards (np.ndarray): expected reward ``R[s, a]`` (1 for entering the goal).
        terminal (np.ndarray): bool mask of holes and goal, shape ``[S]``.
        initial (np.ndarray): initial-state distribution, shape ``[S]``.
        desc (np.ndarray): the map as a ``[rows, cols]`` byte array.

    Examples:
        >>> mdp = frozenlake_mdp("4x4", 3 / 4)
        >>> mdp.num_states, mdp.transitions[0, 2].round(3).tolist()[:5]  # RIGHT from the start
        (16, [0.125, 0.75, 0.0, 0.0, 0.125])
        >>> bool(np.allclose(mdp.transitions.sum(-1), 1.0))
        True
    """

    transitions: np.ndarray
    rewards: np.ndarray
    terminal: np.ndarray
    initial: np.ndarray
    desc: np.ndarray

    @property
    def num_states(self) -> int:
        """Number of states ``S`` (cells of the map)."""
        return self.transitions.shape[0]


@lru_cache(maxsize=32)
def _mdp_cached(map_name: str, success_rate: float, shift: str) -> FrozenLakeMDP:
    from gymnasium.envs.toy_text.frozen_lake import FrozenLakeEnv

    env = FrozenLakeEnv(map_name=map_name, is_slippery=True, success_rate=success_rate)
    env = apply_shift(env, shift, kind="frozenlake").unwrapped
    n_s, n_a = env.observation_space.n, env.action_space.n
    transitions = np.zeros((n_s, n_a, n_s))
    rewards = np.zeros((n_s, n_a))
    for s in range(n_s):
        for a in range(n_a):
            for prob, s_next, reward, _ in env.P[s][a]:
                transitions[s, a, s_next] += prob
                rewards[s, a] += prob * reward
    terminal = np.isin(env.desc.ravel(), [b"G", b"H"])
    for arr in (transitions, rewards, terminal):
        arr.setflags(write=False)
    initial = env.initial_state_distrib.copy()
    initial.setflags(write=False)
    return FrozenLakeMDP(transitions, rewards, terminal, initial, env.desc.copy())


def frozenlake_mdp(
    map_name: str = "4x4", success_rate: float = 3 / 4, shift: str = "none"
) -> FrozenLakeMDP:
    """Builds the exact tabular model of slippery ``FrozenLake-v1``.

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): probability of moving in the intended direction; the two
            perpendicular directions share the rest equally (``shift="none"``) or the
            clockwise one takes all of it (``shift="biased_slip"``).
        shift (str): ``"none"`` (default) or ``"biased_slip"``.

    Examples:
        >>> mdp = frozenlake_mdp("4x4", 3 / 4)
        >>> mdp.transitions.shape, int(mdp.terminal.sum())
        ((16, 4, 16), 5)
    """
    if not 0.0 <= success_rate <= 1.0:
        raise ValueError(f"success_rate must be in [0, 1], got {success_rate}.")
    check_shift(shift, "frozenlake")
    return _mdp_cached(map_name, float(success_rate), shift)


def frozenlake_transition_matrix(
    map_name: str = "4x4", success_rate: float = 3 / 4, shift: str = "none"
) -> np.ndarray:
    """Returns ``P[s, a, s']`` of slippery Frozen-Lake (holes and goal are absorbing).

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): probability of the intended move.
        shift (str): ``"none"`` or ``"biased_slip"``.

    Returns:
        np.ndarray: ``P[s, a, s']``, ``[S, 4, S]``, each row summing to 1.

    Examples:
        >>> P = frozenlake_transition_matrix("4x4", 2 / 3)
        >>> bool(np.allclose(P.sum(-1), 1.0))
        True
        >>> round(float(P[0, 2, 1]), 4)  # RIGHT from the start: intended move
        0.6667
        >>> P = frozenlake_transition_matrix("4x4", 2 / 3, shift="biased_slip")
        >>> round(float(P[0, 2, 0]), 4), float(P[0, 2, 4])  # slips go up (stay), never down
        (0.3333, 0.0)
    """
    return frozenlake_mdp(map_name, success_rate, shift).transitions.copy()


def _q_backup(mdp: FrozenLakeMDP, values: np.ndarray, gamma: float) -> np.ndarray:
    q = mdp.rewards + gamma * mdp.transitions @ values
    q[mdp.terminal] = 0.0
    return q


def frozenlake_optimal_policy(
    map_name: str = "4x4",
    success_rate: float = 3 / 4,
    *,
    gamma: float = 0.99,
    tol: float = 1e-12,
    max_iters: int = 100_000,
    shift: str = "none",
) -> np.ndarray:
    """Greedy stationary policy of discounted value iteration (ties -> lowest action).

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): intended-move probability of the MDP to solve.

    Keyword Args:
        gamma (float): discount factor, in ``(0, 1)``. Defaults to ``0.99``.
        tol (float): sup-norm stopping tolerance.
        max_iters (int): iteration cap.
        shift (str): ``"none"`` (default) or ``"biased_slip"``.

    Examples:
        >>> frozenlake_optimal_policy("4x4", 3 / 4).tolist()
        [1, 3, 1, 3, 0, 0, 1, 0, 2, 1, 0, 0, 0, 2, 2, 0]
    """
    if not 0.0 < gamma < 1.0:
        raise ValueError(f"gamma must be in (0, 1), got {gamma}.")
    mdp = frozenlake_mdp(map_name, success_rate, shift)
    values = np.zeros(mdp.num_states)
    for _ in range(max_iters):
        q = _q_backup(mdp, values, gamma)
        new_values = q.max(1)
        if np.abs(new_values - values).max() < tol:
            values = new_values
            break
        values = new_values
    # one more backup so that the greedy policy matches the converged values exactly
    return _q_backup(mdp, values, gamma).argmax(1)


def frozenlake_success_probability(
    policy: np.ndarray,
    map_name: str = "4x4",
    success_rate: float = 3 / 4,
    *,
    horizon: int = FROZENLAKE_HORIZON,
    per_state: bool = False,
    shift: str = "none",
) -> float | np.ndarray:
    """Exact probability that a policy reaches the goal within ``horizon`` steps.

    Args:
        policy (np.ndarray): either deterministic actions ``[S]`` (ints) or a stochastic
            policy ``[S, 4]`` (rows sum to one).
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): intended-move probability of the environment.

    Keyword Args:
        horizon (int): number of steps (the env's time limit). Defaults to 100.
        per_state (bool): return the probability from every start state instead of
            the expectation over the initial distribution.
        shift (str): ``"none"`` (default) or ``"biased_slip"``.

    Examples:
        >>> pi = frozenlake_optimal_policy("4x4", 3 / 4)
        >>> round(frozenlake_success_probability(pi, "4x4", 2 / 3), 4)
        0.6915
        >>> uniform = np.full((16, 4), 0.25)
        >>> round(frozenlake_success_probability(uniform, "4x4", 2 / 3), 4)
        0.0139
    """
    mdp = frozenlake_mdp(map_name, success_rate, shift)
    n_s = mdp.num_states
    policy = np.asarray(policy)
    if policy.ndim == 1:
        if policy.shape != (n_s,):
            raise ValueError(f"A deterministic policy needs shape ({n_s},), got {policy.shape}.")
        probs = np.eye(4)[policy.astype(np.int64)]
    elif policy.shape == (n_s, 4):
        probs = policy.astype(np.float64)
        if not np.allclose(probs.sum(-1), 1.0):
            raise ValueError("Rows of a stochastic policy must sum to one.")
    else:
        raise ValueError(f"policy must have shape ({n_s},) or ({n_s}, 4), got {policy.shape}.")
    # Policy-induced chain: P_pi[s, s'] and expected one-step reward r_pi[s].
    p_pi = np.einsum("sa,sat->st", probs, mdp.transitions)
    r_pi = (probs * mdp.rewards).sum(1)
    p_pi[mdp.terminal] = 0.0
    r_pi[mdp.terminal] = 0.0
    values = np.zeros(n_s)
    for _ in range(int(horizon)):
        values = r_pi + p_pi @ values
    return values if per_state else float(mdp.initial @ values)


@dataclass(frozen=True)
class FrozenLakeSolution:
    """Result of :func:`frozenlake_value_iteration` (success probabilities from the start).

    Attributes:
        optimal_policy (np.ndarray): greedy stationary policy of discounted VI, ``[S]``.
        optimal_success (float): its success probability within the horizon.
        policy_success (float | None): success probability of the given policy, if any.
        random_success (float): success probability of the uniformly random policy.
        finite_horizon_optimum (float): best achievable with a time-dependent policy.

    Examples:
        >>> solution = frozenlake_value_iteration("4x4", 3 / 4)
        >>> solution.optimal_policy.shape, round(solution.optimal_success, 4)
        ((16,), 0.803)
        >>> solution.random_success < solution.optimal_success <= solution.finite_horizon_optimum
        True
    """

    optimal_policy: np.ndarray
    optimal_success: float
    policy_success: float | None
    random_success: float
    finite_horizon_optimum: float


def frozenlake_value_iteration(
    map_name: str = "4x4",
    success_rate: float = 3 / 4,
    *,
    policy: np.ndarray | None = None,
    gamma: float = 0.99,
    horizon: int = FROZENLAKE_HORIZON,
    shift: str = "none",
) -> FrozenLakeSolution:
    """Solves slippery Frozen-Lake and evaluates policies exactly.

    Args:
        map_name (str): ``"4x4"`` or ``"8x8"``.
        success_rate (float): intended-move probability of the environment.

    Keyword Args:
        policy (np.ndarray, optional): a deterministic ``[S]`` or stochastic ``[S, 4]``
            policy to evaluate in this environment (e.g. the policy optimal elsewhere).
        gamma (float): discount used to pick the optimal stationary policy.
        horizon (int): time limit for the success probabilities.
        shift (str): ``"none"`` (default) or ``"biased_slip"``.

    Examples:
        >>> offline = frozenlake_value_iteration("4x4", 3 / 4)
        >>> online = frozenlake_value_iteration("4x4", 2 / 3, policy=offline.optimal_policy)
        >>> round(online.policy_success, 4), round(online.optimal_success, 4)
        (0.6915, 0.7082)
    """
    mdp = frozenlake_mdp(map_name, success_rate, shift)
    optimal = frozenlake_optimal_policy(map_name, success_rate, gamma=gamma, shift=shift)
    values = np.zeros(mdp.num_states)
    for _ in range(int(horizon)):
        values = _q_backup(mdp, values, 1.0).max(1)
    uniform = np.full((mdp.num_states, 4), 0.25)
    return FrozenLakeSolution(
        optimal_policy=optimal,
        optimal_success=frozenlake_success_probability(
            optimal, map_name, success_rate, horizon=horizon, shift=shift
        ),
        policy_success=None
        if policy is None
        else frozenlake_success_probability(
            policy, map_name, success_rate, horizon=horizon, shift=shift
        ),
        random_success=frozenlake_success_probability(
            uniform, map_name, success_rate, horizon=horizon, shift=shift
        ),
        finite_horizon_optimum=float(mdp.initial @ values),
    )
