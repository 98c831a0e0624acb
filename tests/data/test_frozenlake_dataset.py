"""Epsilon-greedy Frozen-Lake data: one-hot layout, behaviour policy, exact references."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_dual.data import (
    generate_frozenlake_dataset,
    load_or_generate_frozenlake_dataset,
    validate_transitions,
)
from torchrl_dual.envs import frozenlake_mdp, frozenlake_optimal_policy


@pytest.fixture(scope="module")
def data():
    return generate_frozenlake_dataset("4x4", 20_000, seed=0, epsilon=0.3)


def test_data_has_one_hot_observations_and_actions_in_the_layout(data):
    td = validate_transitions(data.transitions, obs_dim=16, action_dim=4)
    for key in ("observation", "action", ("next", "observation")):
        assert torch.equal(td[key].sum(-1), torch.ones(len(data)))


def test_greedy_actions_follow_the_policy_optimal_at_three_quarters(data):
    greedy = torch.as_tensor(frozenlake_optimal_policy("4x4", 3 / 4))
    states = data.transitions["observation"].argmax(-1)
    agree = (data.transitions["action"].argmax(-1) == greedy[states]).float().mean().item()
    assert agree == pytest.approx(1 - 0.3 + 0.3 / 4, abs=0.02)


def test_episodes_end_in_holes_or_goal_and_reward_marks_the_goal(data):
    td = data.transitions
    desc = frozenlake_mdp("4x4").desc.ravel()
    cells = desc[td["next", "observation"].argmax(-1).numpy()]
    terminated = td["next", "terminated"].squeeze(-1).numpy()
    assert np.isin(cells[terminated], [b"H", b"G"]).all()
    assert np.array_equal(td["next", "reward"].squeeze(-1).numpy() == 1.0, cells == b"G")


def test_references_are_exact_success_probabilities_in_the_online_env(data):
    assert data.reference_min == pytest.approx(0.01394, abs=1e-5)
    assert data.reference_max == pytest.approx(0.7082, abs=1e-4)
    refs = data.metadata["references"]
    assert refs["greedy_success_eval"] == pytest.approx(0.6915, abs=1e-4)
    successes = data.transitions["next", "reward"].sum().item()
    episodes = data.transitions["next", "done"].sum().item()
    assert successes / episodes == pytest.approx(refs["behaviour_success_offline"], abs=0.03)


def test_cached_frozenlake_data_round_trips(tmp_path):
    first = load_or_generate_frozenlake_dataset("4x4", 300, 0, tmp_path, epsilon=0.5)
    again = load_or_generate_frozenlake_dataset("4x4", 300, 0, tmp_path, epsilon=0.5)
    assert (first.transitions == again.transitions).all()
    assert again.metadata["epsilon"] == 0.5
