"""relabel_to_goal: D4RL's single-goal rewards and terminals on goal-reaching data."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_dual.data.goal_relabel import relabel_to_goal
from torchrl_dual.data.transition_layout import make_transitions, validate_transitions


def random_walks(episodes: int = 5, steps: int = 40, seed: int = 0):
    rng = np.random.default_rng(seed)
    obs, nxt, ep, trunc = [], [], [], []
    for k in range(episodes):
        path = np.cumsum(rng.normal(0, 0.3, (steps + 1, 4)), 0)
        obs.append(path[:-1])
        nxt.append(path[1:])
        ep.append(np.full(steps, k))
        trunc.append(np.arange(steps) == steps - 1)
    cat = np.concatenate
    n = episodes * steps
    return make_transitions(
        cat(obs),
        np.zeros((n, 2)),
        cat(nxt),
        np.full(n, 7.0),
        np.zeros(n, bool),
        cat(trunc),
        cat(ep),
    )


def test_rewards_and_terminals_are_the_hand_computed_ones():
    td = random_walks()
    goal = td["next", "observation"][17, :2].numpy() + [0.2, -0.1]  # a visited place
    out = relabel_to_goal(td, goal, radius=0.5)
    xy = td["next", "observation"][:, :2].numpy()
    reached = np.array([np.hypot(*(p - goal)) <= 0.5 for p in xy])
    assert reached.sum() >= 2 and not reached.all()
    assert out["next", "reward"].squeeze(-1).tolist() == reached.astype(float).tolist()
    assert out["next", "terminated"].squeeze(-1).numpy().tolist() == reached.tolist()
    validate_transitions(out)  # done only at an episode's last transition
    # every done transition ends an episode, and nothing else changed
    done = out["next", "done"].squeeze(-1)
    ends = torch.ones_like(done)
    ends[:-1] = out["episode"][1:] != out["episode"][:-1]
    assert torch.equal(done | ends, ends) and torch.equal(done, ends)
    assert torch.equal(out["observation"], td["observation"])
    assert td["next", "reward"].eq(7.0).all()  # the input is left untouched


def test_a_truncated_step_that_reaches_the_goal_is_terminal_not_truncated():
    td = random_walks(1, 5)
    goal = td["next", "observation"][4, :2]
    out = relabel_to_goal(td, goal, radius=1e-6)
    assert out["next", "terminated"][4].item() and not out["next", "truncated"][4].item()


@pytest.mark.parametrize("position", [slice(0, 2), slice(2, 4)])
def test_the_position_entries_are_the_ones_named(position):
    td = random_walks(2, 10)
    goal = td["next", "observation"][3, position]
    out = relabel_to_goal(td, goal, radius=1e-6, position=position)
    assert out["next", "reward"][3].item() == 1.0
