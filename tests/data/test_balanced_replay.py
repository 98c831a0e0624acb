"""Tests for OFF2ON's balanced replay: sampling in proportion to density-ratio priorities."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import LazyTensorStorage, ReplayBuffer

from torchrl_dual.data.balanced_replay import PRIORITY_RANGE, BalancedReplayBuffer

N_OFF, N_ON = 6, 4
CHI2_DF9_P001 = 27.877  # the chi-square quantile 0.999 with 9 degrees of freedom


# ----------------------------------------------------------------------------- factories
class _ExpRatio(nn.Module):
    """A fake ratio network ``w(s, a) = exp(3 a_0)``."""

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return torch.exp(3.0 * action[..., :1])


def _transitions(start: int, n: int) -> TensorDict:
    """Transition ``i`` carries ``x = i`` (its global index) and the action ``a_0 = i / 10``."""
    x = torch.arange(start, start + n, dtype=torch.float32)
    action = torch.stack([x / 10, torch.zeros(n)], -1)
    return TensorDict(x=x, observation=torch.zeros(n, 3), action=action, batch_size=[n])


def _mock_buffer(online: int = N_ON, **kwargs) -> BalancedReplayBuffer:
    offline = ReplayBuffer(storage=LazyTensorStorage(N_OFF))
    offline.extend(_transitions(0, N_OFF))
    kwargs.setdefault("online_capacity", N_ON)
    ratio = TensorDictModule(
        _ExpRatio(), in_keys=["observation", "action"], out_keys=["density_ratio"]
    )
    rb = BalancedReplayBuffer(offline, batch_size=1000, ratio_network=ratio, **kwargs)
    if online:
        rb.extend(_transitions(N_OFF, online))
    return rb


def _counts(rb: BalancedReplayBuffer, draws: int) -> torch.Tensor:
    index = torch.cat([rb.sample()["index"] for _ in range(draws // 1000)])
    return torch.bincount(index, minlength=len(rb)).float()


# ----------------------------------------------------------------------------- sampling
def test_sampling_frequencies_follow_the_priorities_chi_square():
    rb = _mock_buffer()
    priority = torch.tensor([0.5, 1, 2, 3, 4, 5, 1, 2, 8, 0.25])
    rb.update_priority(torch.arange(10), priority)
    torch.manual_seed(0)
    counts = _counts(rb, 40_000)
    expected = 40_000 * priority / priority.sum()
    chi2 = float(((counts - expected) ** 2 / expected).sum())
    assert chi2 < CHI2_DF9_P001
    # the highest-priority transition is drawn ~32 times as often as the lowest
    assert abs(float(counts[8] / counts[9]) / 32 - 1) < 0.15
    torch.testing.assert_close(rb.probabilities(), priority / priority.sum())


def test_a_higher_density_ratio_is_drawn_more_often_after_a_refresh():
    rb = _mock_buffer(temperature=1.0)
    everything = rb.gather(torch.arange(len(rb)))
    everything["index"] = torch.arange(len(rb))
    rb.refresh_priorities(everything, reference=everything[:N_OFF])
    torch.manual_seed(1)
    counts = _counts(rb, 40_000)
    w = torch.exp(3.0 * torch.arange(10) / 10)  # T = 1: p ∝ w
    expected = 40_000 * w / w.sum()
    assert float(((counts - expected) ** 2 / expected).sum()) < CHI2_DF9_P001
    assert bool((counts[1:] > counts[:-1]).all())  # monotone in w, here in the index


def test_refresh_sets_the_clipped_normalised_ratio_of_the_sampled_transitions():
    rb = _mock_buffer(temperature=5.0)
    torch.manual_seed(2)
    batch = rb.sample(32)
    reference = rb.gather(torch.tensor([0, 2, 4]))
    priority = rb.refresh_priorities(batch, reference)
    w_ref = torch.exp(3.0 * torch.tensor([0.0, 0.2, 0.4]))
    expected = torch.exp(3.0 * batch["action"][:, 0]) ** 0.2 / (w_ref**0.2).mean()
    torch.testing.assert_close(priority, expected)
    torch.testing.assert_close(rb.priorities[batch["index"]], expected)
    # untouched transitions keep their priority
    untouched = torch.ones(len(rb), dtype=torch.bool)
    untouched[batch["index"]] = False
    assert bool((rb.priorities[untouched] == 1.0).all())
    # a ratio batch (offline and online, flagged) normalises over its offline part only
    ratio_batch = rb.ratio_batch(16)
    priority = rb.refresh_priorities(batch, ratio_batch)
    w_off = torch.exp(3.0 * ratio_batch["action"][:16, 0])
    torch.testing.assert_close(
        priority, torch.exp(3.0 * batch["action"][:, 0]) ** 0.2 / (w_off**0.2).mean()
    )


def test_priorities_are_clipped_to_the_range():
    rb = _mock_buffer()
    rb.update_priority(torch.tensor([0, 1]), torch.tensor([1e-9, 1e9]))
    assert rb.priorities[0] == PRIORITY_RANGE[0] and rb.priorities[1] == PRIORITY_RANGE[1]


def test_new_online_transitions_get_the_running_max_priority():
    rb = _mock_buffer(online=2)
    rb.update_priority(torch.tensor([3]), torch.tensor([7.0]))
    rb.update_priority(torch.tensor([3]), torch.tensor([0.5]))  # the maximum is a running one
    index = rb.extend(_transitions(N_OFF + 2, 2))
    assert index.tolist() == [2, 3]
    assert rb.priorities[N_OFF + 2 : N_OFF + 4].tolist() == [7.0, 7.0]
    assert rb.priorities[N_OFF : N_OFF + 2].tolist() == [1.0, 1.0]
    rb.update_priority(torch.tensor([N_OFF]), torch.tensor([0.1]))
    rb.extend(_transitions(100, 1))  # full: first in, first out, at the max priority
    assert rb.priorities[N_OFF] == 7.0 and rb.online_buffer[0]["x"] == 100


def test_samples_carry_their_own_indices_and_ratio_batches_their_source():
    rb = _mock_buffer()
    torch.manual_seed(3)
    batch = rb.sample(500)
    assert batch.shape == (500,)
    assert bool((batch["x"] == batch["index"].float()).all())
    assert (batch["index"] >= N_OFF).any() and (batch["index"] < N_OFF).any()
    ratio = rb.ratio_batch(64)
    assert ratio.shape == (128,)
    assert bool((ratio["online"] == (ratio["x"] >= N_OFF)).all())
    assert int(ratio["online"].sum()) == 64


def test_before_online_data_sampling_is_uniform_over_the_offline_data():
    rb = _mock_buffer(online=0)
    torch.testing.assert_close(rb.probabilities(), torch.full((N_OFF,), 1 / N_OFF))
    assert len(rb) == N_OFF and bool((rb.sample(100)["index"] < N_OFF).all())


def test_state_dict_round_trip_restores_the_priorities():
    rb = _mock_buffer()
    rb.update_priority(torch.arange(3), torch.tensor([2.0, 3.0, 9.0]))
    other = _mock_buffer()
    other.load_state_dict(rb.state_dict())
    torch.testing.assert_close(other.probabilities(), rb.probabilities())
    assert other.max_priority == 9.0
    with pytest.raises(ValueError, match="online capacity"):
        _mock_buffer(online_capacity=8).load_state_dict(rb.state_dict())


def test_bad_arguments_name_the_fix():
    offline = ReplayBuffer(storage=LazyTensorStorage(N_OFF))
    offline.extend(_transitions(0, N_OFF))
    with pytest.raises(ValueError, match="exactly one"):
        BalancedReplayBuffer(offline)
    with pytest.raises(ValueError, match="temperature"):
        BalancedReplayBuffer(offline, online_capacity=2, temperature=0.0)
    with pytest.raises(ValueError, match="extend"):
        _mock_buffer(online=0).ratio_batch(4)
    no_net = BalancedReplayBuffer(offline, online_capacity=2, batch_size=4)
    with pytest.raises(ValueError, match="ratio_network"):
        no_net.refresh_priorities(no_net.sample())
