"""Tests of ``WindowReplayBuffer`` (``torchrl_dual/diffusion/windows.py``)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_dual.diffusion import WindowReplayBuffer

pytestmark = pytest.mark.usefixtures("seeded")

# Episodes shorter than, equal to and longer than a horizon-4 window (5 rows).
LENGTHS = (1, 3, 5, 7, 12, 2, 4, 9, 5, 1)
HORIZON = 4


def _transitions(lengths=LENGTHS, traj_key="episode"):
    episode = torch.cat([torch.full((n,), i) for i, n in enumerate(lengths)])
    step = torch.cat([torch.arange(n) for n in lengths])
    total = int(episode.numel())
    return TensorDict(
        {
            "observation": torch.randn(total, 3),
            "action": torch.randn(total, 2),
            traj_key: episode,
            "step": step,
            "global_step": torch.arange(total),
        },
        batch_size=[total],
    )


def test_windows_never_cross_an_episode_boundary():
    buffer = WindowReplayBuffer(_transitions(), horizon=HORIZON, batch_size=32)
    seen = set()
    for _ in range(20):
        windows = buffer.sample()
        assert windows.batch_size == (32, HORIZON + 1)
        episode = windows["episode"]
        assert (episode == episode[:, :1]).all()
        assert (windows["step"].diff(dim=1) == 1).all()
        assert (windows["global_step"].diff(dim=1) == 1).all()
        seen |= set(episode[:, 0].tolist())
    long_enough = {i for i, n in enumerate(LENGTHS) if n >= HORIZON + 1}
    assert seen == long_enough


def test_windows_carry_the_stored_values_of_their_steps():
    data = _transitions()
    windows = WindowReplayBuffer(data, horizon=HORIZON, batch_size=16).sample()
    assert torch.equal(windows["observation"], data["observation"][windows["global_step"]])
    assert torch.equal(windows["action"], data["action"][windows["global_step"]])


def test_an_episode_exactly_one_window_long_is_sampled_whole():
    buffer = WindowReplayBuffer(_transitions((2, 5, 3)), horizon=HORIZON, batch_size=8)
    windows = buffer.sample()
    assert (windows["episode"] == 1).all()
    assert (windows["step"] == torch.arange(HORIZON + 1)).all()


def test_no_episode_long_enough_is_an_error_naming_the_longest():
    with pytest.raises(ValueError, match=r"No episode holds the 5 steps .*longest: 4"):
        WindowReplayBuffer(_transitions((1, 4, 3)), horizon=HORIZON, batch_size=8)


def test_a_missing_episode_key_is_an_error_naming_the_key():
    with pytest.raises(KeyError, match="'episode'"):
        WindowReplayBuffer(_transitions(traj_key="traj"), horizon=HORIZON, batch_size=8)


def test_a_custom_episode_key_is_used():
    buffer = WindowReplayBuffer(
        _transitions(traj_key="traj"), horizon=HORIZON, batch_size=8, traj_key="traj"
    )
    windows = buffer.sample()
    assert (windows["traj"] == windows["traj"][:, :1]).all()


def test_a_batched_transition_tensordict_is_rejected():
    data = _transitions((5, 5)).reshape(2, 5)
    with pytest.raises(ValueError, match=r"flat \[N\] TensorDict, got batch_size \(2, 5\)"):
        WindowReplayBuffer(data, horizon=HORIZON, batch_size=8)
