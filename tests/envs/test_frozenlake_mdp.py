"""Exact Frozen-Lake dynamics and success probabilities (the paper's slip shift)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from torchrl_dual.envs import (
    frozenlake_mdp,
    frozenlake_optimal_policy,
    frozenlake_success_probability,
    frozenlake_transition_matrix,
    frozenlake_value_iteration,
)


def test_transition_matrix_has_the_intended_and_perpendicular_slip_probabilities():
    P = frozenlake_transition_matrix("4x4", 3 / 4)
    assert P.shape == (16, 4, 16)
    np.testing.assert_allclose(P.sum(-1), 1.0)
    # from cell 5 (a hole) nothing moves; from cell 6, RIGHT goes to 7 w.p. 3/4, up/down 1/8
    assert P[5, 2, 5] == 1.0
    assert P[6, 2, 7] == pytest.approx(3 / 4)
    assert P[6, 2, 2] == pytest.approx(1 / 8) and P[6, 2, 10] == pytest.approx(1 / 8)
    mdp = frozenlake_mdp("4x4", 3 / 4)
    assert mdp.terminal.nonzero()[0].tolist() == [5, 7, 11, 12, 15]


def test_policy_optimal_at_three_quarters_succeeds_0692_under_two_thirds():
    offline = frozenlake_value_iteration("4x4", 3 / 4)
    online = frozenlake_value_iteration("4x4", 2 / 3, policy=offline.optimal_policy)
    assert online.policy_success == pytest.approx(0.692, abs=1e-3)
    assert online.policy_success == pytest.approx(0.69149, abs=1e-5)


def test_optimal_policy_under_two_thirds_succeeds_0708():
    online = frozenlake_value_iteration("4x4", 2 / 3)
    assert online.optimal_success == pytest.approx(0.708, abs=1e-3)
    assert (
        online.optimal_success
        > frozenlake_value_iteration(
            "4x4", 2 / 3, policy=frozenlake_optimal_policy("4x4", 3 / 4)
        ).policy_success
    )


def test_random_policy_and_time_dependent_optimum_bracket_the_optimal_policy():
    sol = frozenlake_value_iteration("4x4", 2 / 3)
    assert sol.random_success == pytest.approx(0.01394, abs=1e-5)
    assert sol.random_success < sol.optimal_success <= sol.finite_horizon_optimum
    assert sol.finite_horizon_optimum == pytest.approx(0.8392, abs=1e-4)


def test_exact_success_probability_matches_monte_carlo_in_the_gymnasium_env():
    policy = frozenlake_optimal_policy("4x4", 3 / 4)
    exact = frozenlake_success_probability(policy, "4x4", 3 / 4)
    env = gym.make("FrozenLake-v1", map_name="4x4", is_slippery=True, success_rate=3 / 4)
    episodes, wins = 3000, 0
    for ep in range(episodes):
        state, _ = env.reset(seed=ep)
        done = False
        while not done:
            state, reward, terminated, truncated, _ = env.step(int(policy[state]))
            done = terminated or truncated
        wins += reward
    assert abs(wins / episodes - exact) < 4 * np.sqrt(exact * (1 - exact) / episodes)


def test_policy_with_a_wrong_shape_raises_a_value_error():
    with pytest.raises(ValueError, match="shape"):
        frozenlake_success_probability(np.zeros(15, int), "4x4", 3 / 4)
    with pytest.raises(ValueError, match="sum to one"):
        frozenlake_success_probability(np.ones((16, 4)), "4x4", 3 / 4)
