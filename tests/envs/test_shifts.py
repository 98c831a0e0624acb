"""Online dynamics shifts (``torchrl_dual.envs.SHIFTS``): they change what the same state
and action lead to, the TorchRL env and the Gymnasium env agree, and the exact
Frozen-Lake model matches the shifted env."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from recipe_runner import run_module

from torchrl_dual.envs import (
    SHIFTS,
    RotatedAction,
    apply_shift,
    biased_slip_table,
    frozenlake_mdp,
    frozenlake_optimal_policy,
    frozenlake_success_probability,
    make_frozenlake_env,
    make_pointmaze_env,
    make_pointmaze_gym_env,
    shift_names,
)

POINTMAZE_SHIFTS = [name for name in shift_names("pointmaze") if name != "none"]
ACTION = np.array([0.8, -0.3])


def next_states(shift: str, steps: int = 5, **kw) -> np.ndarray:
    """The point's state after each of ``steps`` identical actions from the same reset."""
    env = make_pointmaze_gym_env("umaze", shift=shift, **kw)
    env.reset(seed=3)
    return np.stack([env.step(ACTION)[0]["observation"] for _ in range(steps)])


def test_every_shift_applies_to_the_env_kinds_it_names():
    assert shift_names("pointmaze") == ("none", "rotation", "damping", "mass")
    assert shift_names("frozenlake") == ("none", "biased_slip", "biased_slip_cw")
    assert shift_names("locomotion") == ("none", "friction", "gravity", "kinematic", "morphology")
    kinds = ("pointmaze", "frozenlake", "locomotion")
    assert set(SHIFTS) == set().union(*(shift_names(kind) for kind in kinds))


@pytest.mark.parametrize("shift", POINTMAZE_SHIFTS)
def test_a_pointmaze_shift_changes_the_next_state_of_the_same_state_and_action(shift):
    plain = next_states("none")
    np.testing.assert_array_equal(plain, next_states("none"))  # deterministic without a shift
    shifted = next_states(shift)
    assert not np.allclose(shifted[0], plain[0])  # already after one step
    assert np.abs(shifted - plain).max() > 1e-2


def test_rotation_rotates_the_executed_action_by_the_angle():
    env = make_pointmaze_gym_env("umaze", shift="rotation", shift_angle=90)
    assert isinstance(env, RotatedAction)
    np.testing.assert_allclose(env.action(np.array([1.0, 0.0])), [0.0, 1.0], atol=1e-12)
    # a 90 degree rotation of (0.8, -0.3) is (0.3, 0.8): same next state as that action
    np.testing.assert_allclose(
        next_states("rotation", shift_angle=90)[0],
        _step_plain(np.array([0.3, 0.8])),
        atol=1e-12,
    )
    # the default angle is 60 degrees
    assert make_pointmaze_gym_env("umaze", shift="rotation").angle == 60.0
    np.testing.assert_array_equal(next_states("rotation", shift_angle=0), next_states("none"))


def _step_plain(action: np.ndarray) -> np.ndarray:
    env = make_pointmaze_gym_env("umaze")
    env.reset(seed=3)
    return env.step(action)[0]["observation"]


@pytest.mark.parametrize(("shift", "field"), [("damping", "dof_damping"), ("mass", "body_mass")])
def test_physical_shifts_scale_the_mujoco_model(shift, field):
    plain = make_pointmaze_gym_env("umaze").unwrapped.point_env.model
    env = make_pointmaze_gym_env("umaze", shift=shift, shift_scale=4.0)
    model = env.unwrapped.point_env.model
    np.testing.assert_allclose(getattr(model, field)[-2:], 4.0 * getattr(plain, field)[-2:])
    default = make_pointmaze_gym_env("umaze", shift=shift)
    assert default.scale == SHIFTS[shift].default_scale
    np.testing.assert_array_equal(
        next_states(shift, shift_scale=1.0), next_states("none")
    )  # a scale of 1 changes nothing


def test_a_heavier_point_accelerates_less():
    light = next_states("none", steps=1)[0, 2:]
    heavy = next_states("mass", steps=1, shift_scale=10.0)[0, 2:]
    assert np.linalg.norm(heavy) < 0.2 * np.linalg.norm(light)


@pytest.mark.parametrize("shift", ["none", *POINTMAZE_SHIFTS])
def test_the_torchrl_env_and_the_gym_env_agree_under_a_shift(shift):
    def torchrl_step(name: str) -> np.ndarray:
        env = make_pointmaze_env("umaze", shift=name, seed=3)
        td = env.reset()
        td["action"] = torch.as_tensor(ACTION, dtype=torch.float32)
        return env.step(td)["next", "observation"][:4].double().numpy()

    # from rest, the velocity after one step depends on the action and the dynamics only
    observation = torchrl_step(shift)
    np.testing.assert_allclose(observation[2:], next_states(shift, steps=1)[0, 2:], atol=1e-5)
    if shift != "none":
        assert not np.allclose(observation, torchrl_step("none"))


def test_pointmaze_shift_errors_name_the_options():
    with pytest.raises(ValueError, match=r"Valid names: \['none', 'rotation', 'damping', 'mass'\]"):
        make_pointmaze_env("umaze", shift="biased_slip")
    with pytest.raises(ValueError, match="scale must be > 0"):
        make_pointmaze_gym_env("umaze", shift="mass", shift_scale=0.0)
    with pytest.raises(ValueError, match="needs a PointMaze env"):
        apply_shift(gym.make("FrozenLake-v1"), "damping")
    with pytest.raises(ValueError, match="needs slippery Frozen-Lake"):
        apply_shift(gym.make("FrozenLake-v1", is_slippery=False), "biased_slip")


# ----------------------------------------------------------------------------- Frozen-Lake
@pytest.mark.parametrize(("shift", "turn"), [("biased_slip", +1), ("biased_slip_cw", -1)])
def test_biased_slip_sends_every_slip_to_one_side(shift, turn):
    rate = 2 / 3
    plain = frozenlake_mdp("8x8", rate).transitions
    shifted = frozenlake_mdp("8x8", rate, shift).transitions
    np.testing.assert_allclose(shifted.sum(-1), 1.0)
    # cell 9 (row 1, col 1) is frozen and has four distinct neighbours
    up, left, down, right = 1, 8, 17, 10
    neighbour = {0: left, 1: down, 2: right, 3: up}
    for a in range(4):
        slip = neighbour[(a + turn) % 4]
        other = neighbour[(a - turn) % 4]
        assert shifted[9, a, neighbour[a]] == pytest.approx(rate)
        assert shifted[9, a, slip] == pytest.approx(1 - rate)
        assert shifted[9, a, other] == 0.0
        assert plain[9, a, other] == pytest.approx((1 - rate) / 2)


@pytest.mark.parametrize("shift", ["biased_slip", "biased_slip_cw"])
def test_the_exact_model_matches_monte_carlo_transitions_of_the_shifted_env(shift):
    env = apply_shift(
        gym.make("FrozenLake-v1", map_name="8x8", is_slippery=True, success_rate=2 / 3), shift
    )
    env.reset(seed=0)
    exact = frozenlake_mdp("8x8", 2 / 3, shift).transitions
    n = 4000
    for state, action in [(9, 0), (9, 3), (0, 2), (27, 1)]:
        counts = np.zeros(64)
        for _ in range(n):
            env.unwrapped.s = state
            counts[env.step(action)[0]] += 1
        # 5 standard errors of a binomial frequency
        tol = 5 * np.sqrt(exact[state, action] * (1 - exact[state, action]) / n) + 1e-9
        assert np.all(np.abs(counts / n - exact[state, action]) <= tol)


def test_the_exact_success_probability_matches_monte_carlo_episodes_under_the_shift():
    offline = frozenlake_optimal_policy("8x8", 3 / 4)
    behaviour = 0.7 * np.eye(4)[offline] + 0.3 / 4  # the data's epsilon-greedy policy
    env = apply_shift(
        gym.make(
            "FrozenLake-v1",
            map_name="8x8",
            is_slippery=True,
            success_rate=2 / 3,
            max_episode_steps=100,
        ),
        "biased_slip_cw",
    )
    rng = np.random.default_rng(0)
    for policy in (offline, behaviour):
        exact = frozenlake_success_probability(policy, "8x8", 2 / 3, shift="biased_slip_cw")
        n, wins = 1500, 0
        for ep in range(n):
            state, _ = env.reset(seed=ep)
            done = False
            while not done:
                action = policy[state] if policy.ndim == 1 else rng.choice(4, p=policy[state])
                state, reward, terminated, truncated, _ = env.step(int(action))
                done = terminated or truncated
            wins += reward
        assert abs(wins / n - exact) <= 5 * np.sqrt(exact * (1 - exact) / n) + 1e-3


@pytest.mark.parametrize("shift", ["biased_slip", "biased_slip_cw"])
def test_biased_slip_changes_the_optimal_policy_on_8x8(shift):
    offline = frozenlake_optimal_policy("8x8", 3 / 4)
    unshifted = frozenlake_optimal_policy("8x8", 2 / 3)
    shifted = frozenlake_optimal_policy("8x8", 2 / 3, shift=shift)
    assert (shifted != unshifted).sum() >= 8
    assert (shifted != offline).sum() >= 8
    # the shifted optimum does strictly better under the shift than either unshifted policy
    best = frozenlake_success_probability(shifted, "8x8", 2 / 3, shift=shift)
    assert best == pytest.approx(1.0)
    for policy in (offline, unshifted):
        assert frozenlake_success_probability(policy, "8x8", 2 / 3, shift=shift) < best - 0.02


def test_biased_slip_leaves_the_offline_optimal_policy_with_nothing_on_8x8():
    offline = frozenlake_optimal_policy("8x8", 3 / 4)
    plain = frozenlake_success_probability(offline, "8x8", 2 / 3)
    shifted = frozenlake_success_probability(offline, "8x8", 2 / 3, shift="biased_slip")
    assert plain == pytest.approx(0.9343, abs=1e-4)
    assert shifted == pytest.approx(0.0, abs=1e-6)


def test_the_torchrl_frozenlake_env_carries_the_shift():
    env = make_frozenlake_env("8x8", 2 / 3, seed=0, shift="biased_slip")
    inner = env.base_env._env.unwrapped
    from gymnasium.envs.toy_text.frozen_lake import FrozenLakeEnv

    expected = biased_slip_table(FrozenLakeEnv(map_name="8x8", success_rate=2 / 3).P, 2 / 3)
    assert inner.P == expected
    plain = make_frozenlake_env("8x8", 2 / 3, seed=0)
    assert plain.base_env._env.unwrapped.P != expected
    rollout = env.rollout(5)
    assert rollout["observation"].shape == (5, 64)
    with pytest.raises(ValueError, match="Valid names"):
        make_frozenlake_env("4x4", shift="rotation")


def test_the_shift_benchmark_prints_both_tables():
    proc = run_module("benchmarks.studies.shifts", "--episodes", "1", "--shifts", "rotation:90")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "| rotation:90 |" in proc.stdout
    assert "| offline-optimal (data: 3/4, symmetric slip) | 0.9343 | 0.0000 |" in proc.stdout
