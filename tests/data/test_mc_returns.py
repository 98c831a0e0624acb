"""Tests for the Monte-Carlo returns-to-go of Cal-QL's bound (torchrl_dual/data/mc_returns.py)."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from torchrl_dual.data import episode_returns, make_transitions, monte_carlo_returns


def _transitions(rewards, episode, terminated=None, truncated=None) -> TensorDict:
    """Flat transitions with the given rewards and episode ids (zero observations)."""
    n = len(rewards)
    terminated = np.zeros(n, bool) if terminated is None else np.asarray(terminated, bool)
    truncated = np.zeros(n, bool) if truncated is None else np.asarray(truncated, bool)
    zeros = np.zeros((n, 1))
    return make_transitions(
        zeros, zeros, zeros, np.asarray(rewards, float), terminated, truncated, episode
    )


def _naive_returns(rewards, episode, gamma, failure=None) -> list[float]:
    """A python loop over each episode, backwards, as Cal-QL's ``calc_return_to_go``."""
    out = [0.0] * len(rewards)
    i = 0
    while i < len(rewards):
        j = i
        while j + 1 < len(rewards) and episode[j + 1] == episode[i]:
            j += 1
        chunk = rewards[i : j + 1]
        if failure is not None and all(r == failure for r in chunk):
            out[i : j + 1] = [failure / (1 - gamma)] * len(chunk)
        else:
            ret = 0.0
            for t in range(j, i - 1, -1):
                ret = rewards[t] + gamma * ret
                out[t] = ret
        i = j + 1
    return out


def test_a_terminated_episode_sums_its_discounted_rewards_up_to_the_terminal():
    td = _transitions([1.0, 2.0, 3.0], [0, 0, 0], terminated=[0, 0, 1])
    got = monte_carlo_returns(td, gamma=0.5).squeeze(-1).tolist()
    assert got == pytest.approx([1 + 0.5 * 2 + 0.25 * 3, 2 + 0.5 * 3, 3.0])


def test_a_truncated_episode_is_not_bootstrapped_past_its_last_step():
    # Cal-QL's code starts the backward pass from 0 at a time limit too: same sums.
    td = _transitions([1.0, 2.0, 3.0], [0, 0, 0], truncated=[0, 0, 1])
    assert monte_carlo_returns(td, gamma=0.5).squeeze(-1).tolist() == pytest.approx(
        [2.75, 3.5, 3.0]
    )


def test_sparse_rewards_all_zero_give_zero_and_the_failure_rule_gives_r_over_one_minus_gamma():
    td = _transitions([0.0, 0.0, 0.0, 0.0], [0] * 4, truncated=[0, 0, 0, 1])
    assert monte_carlo_returns(td, gamma=0.9).abs().max() == 0
    assert monte_carlo_returns(td, gamma=0.9, sparse_failure_reward=0.0).abs().max() == 0
    # Cal-QL's AntMaze rewards 10 r - 5: a failed episode is worth -5 / (1 - γ) everywhere,
    failed = _transitions([-5.0] * 3, [0] * 3, truncated=[0, 0, 1])
    got = monte_carlo_returns(failed, gamma=0.9, sparse_failure_reward=-5.0)
    assert got.squeeze(-1).tolist() == pytest.approx([-50.0] * 3)
    # without the rule it is the finite sum; a successful episode keeps the finite sum.
    plain = monte_carlo_returns(failed, gamma=0.9).squeeze(-1).tolist()
    assert plain == pytest.approx([-5 - 4.5 - 4.05, -5 - 4.5, -5.0])
    success = _transitions([-5.0, -5.0, 5.0], [0] * 3, terminated=[0, 0, 1])
    got = monte_carlo_returns(success, gamma=0.9, sparse_failure_reward=-5.0).squeeze(-1)
    assert got.tolist() == pytest.approx([-5 - 4.5 + 0.81 * 5, -5 + 4.5, 5.0])


def test_episodes_back_to_back_do_not_leak_into_each_other():
    rewards = [1.0, 2.0, 3.0, 10.0, 10.0, -5.0, -5.0]
    td = _transitions(
        rewards,
        [0, 0, 0, 4, 4, 7, 7],
        terminated=[0, 0, 1, 0, 0, 0, 0],
        truncated=[0, 0, 0, 0, 1, 0, 1],
    )
    got = monte_carlo_returns(td, gamma=0.5, sparse_failure_reward=-5.0).squeeze(-1).tolist()
    assert got == pytest.approx([2.75, 3.5, 3.0, 15.0, 10.0, -10.0, -10.0])


def test_a_done_flag_ends_the_sum_even_without_an_id_change():
    td = TensorDict(
        {
            "episode": torch.zeros(3, dtype=torch.long),
            ("next", "reward"): torch.ones(3, 1),
            ("next", "done"): torch.tensor([[False], [True], [False]]),
        },
        [3],
    )
    assert monte_carlo_returns(td, gamma=0.5).squeeze(-1).tolist() == [1.5, 1.0, 1.0]


def test_random_10k_transitions_match_a_naive_python_loop():
    rng = np.random.default_rng(0)
    lengths = rng.integers(1, 300, size=80)
    episode = np.repeat(np.arange(len(lengths)) * 3, lengths)[:10_000]
    n = len(episode)
    rewards = rng.normal(size=n).round(1)
    failed = np.isin(episode, episode[rng.integers(0, n, 10)])  # some all-failure episodes
    rewards[failed] = -1.0
    last = np.r_[episode[1:] != episode[:-1], True]
    terminated = last & (rng.random(n) < 0.5)
    td = _transitions(rewards, episode, terminated=terminated, truncated=last & ~terminated)
    for failure in (None, -1.0):
        got = monte_carlo_returns(td, gamma=0.99, sparse_failure_reward=failure).squeeze(-1)
        expected = _naive_returns(rewards.tolist(), episode.tolist(), 0.99, failure)
        np.testing.assert_allclose(got.numpy(), np.asarray(expected), rtol=1e-5, atol=1e-4)
    assert got.dtype == torch.float32 and got.shape == (n,)


def test_one_million_transitions_take_seconds_printed():
    n = 1_000_000
    gen = torch.Generator().manual_seed(0)
    episode = torch.sort(torch.randint(0, 1000, (n,), generator=gen)).values
    td = TensorDict({"episode": episode, ("next", "reward"): torch.randn(n, 1, generator=gen)}, [n])
    start = time.perf_counter()
    returns = monte_carlo_returns(td, gamma=0.99)
    print(f"monte_carlo_returns: 1M transitions in {time.perf_counter() - start:.2f} s")
    assert returns.shape == (n, 1) and torch.isfinite(returns).all()


def test_episode_returns_of_one_finished_episode_match_the_offline_labels():
    rewards = torch.tensor([[-1.0], [-1.0], [-1.0], [0.0]])
    terminated = torch.tensor([False, False, False, True])
    truncated = torch.zeros(4, dtype=torch.bool)
    td = _transitions(rewards.squeeze(-1).tolist(), [0] * 4, terminated=terminated)
    for failure in (None, -1.0):
        online = episode_returns(rewards, terminated, truncated, 0.9, sparse_failure_reward=failure)
        assert torch.equal(online, monte_carlo_returns(td, 0.9, sparse_failure_reward=failure))
    failed = episode_returns(
        -torch.ones(3),
        truncated[:3],
        torch.tensor([0, 0, 1]).bool(),
        0.9,
        sparse_failure_reward=-1.0,
    )
    assert failed.squeeze(-1).tolist() == pytest.approx([-10.0] * 3)


@pytest.mark.parametrize(
    "flags, message",
    [
        ([0, 0, 0], "needs a finished episode"),
        ([0, 1, 1], "Step 1 of 3 is already done"),
    ],
)
def test_episode_returns_rejects_unfinished_or_several_episodes(flags, message):
    with pytest.raises(ValueError, match=message):
        episode_returns(torch.ones(3), torch.tensor(flags).bool(), torch.zeros(3).bool(), 0.9)


def test_gamma_outside_zero_one_and_missing_keys_are_rejected_with_the_fix():
    td = _transitions([1.0], [0])
    with pytest.raises(ValueError, match=r"gamma must be in \[0, 1\)"):
        monte_carlo_returns(td, gamma=1.0)
    with pytest.raises(KeyError, match="make_transitions"):
        monte_carlo_returns(td.exclude("episode"), gamma=0.9)
