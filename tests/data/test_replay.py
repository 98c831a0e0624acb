"""to_replay_buffer: TensorDictReplayBuffer over RAM or memmap storage."""

from __future__ import annotations

import numpy as np
import pytest
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, SliceSampler

from torchrl_dual.data import make_transitions, to_replay_buffer


def _td(n=30, length=10):
    obs = np.arange(n, dtype=np.float32)[:, None]
    done = (np.arange(n) % length) == length - 1
    return make_transitions(
        obs, np.zeros((n, 1)), obs + 1, np.zeros(n), np.zeros(n, bool), done, np.arange(n) // length
    )


def test_tensor_storage_holds_every_transition_and_samples_batches():
    rb = to_replay_buffer(_td(), batch_size=7)
    assert isinstance(rb._storage, LazyTensorStorage) and len(rb) == 30
    assert rb.sample().batch_size == (7,)


def test_memmap_storage_writes_to_the_scratch_dir(tmp_path):
    rb = to_replay_buffer(_td(), storage="memmap", scratch_dir=tmp_path, max_size=100)
    assert isinstance(rb._storage, LazyMemmapStorage) and len(rb) == 30
    assert any(tmp_path.rglob("*.memmap"))


def test_slice_sampler_draws_windows_from_single_episodes():
    rb = to_replay_buffer(
        _td(), sampler=SliceSampler(slice_len=5, traj_key="episode"), batch_size=50
    )
    episodes = rb.sample()["episode"].reshape(10, 5)
    assert (episodes == episodes[:, :1]).all()


def test_bad_arguments_raise_value_errors():
    with pytest.raises(ValueError, match="storage must be one of"):
        to_replay_buffer(_td(), storage="disk")
    with pytest.raises(ValueError, match="smaller than the 30 transitions"):
        to_replay_buffer(_td(), max_size=10)
    with pytest.raises(ValueError, match="missing the keys"):
        to_replay_buffer(_td().exclude("episode"))
