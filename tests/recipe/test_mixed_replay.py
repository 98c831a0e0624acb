"""``replay=mixed``: TorchRL's ``OfflineToOnlineReplayBuffer`` over the run's offline buffer."""

from __future__ import annotations

import warnings
from types import SimpleNamespace

import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer

from torchrl_dual.recipe.o2o.replays import make_mixed_replay


def _run(offline_fraction: float, batch_size: int = 8, n_offline: int = 50) -> SimpleNamespace:
    offline = ReplayBuffer(
        storage=LazyTensorStorage(n_offline), sampler=RandomSampler(), batch_size=batch_size
    )
    offline.extend(TensorDict({"source": torch.zeros(n_offline, 1)}, batch_size=[n_offline]))
    cfg = SimpleNamespace(
        online=SimpleNamespace(offline_fraction=offline_fraction, batch_size=batch_size),
        budget=SimpleNamespace(online_frames=20),
    )
    return SimpleNamespace(
        cfg=cfg, offline_buffer=offline, learner=SimpleNamespace(extra_online_capacity=0)
    )


def test_mixed_batches_split_as_configured_without_a_batch_size_warning():
    run = _run(offline_fraction=0.25)
    replay = make_mixed_replay(run)
    replay.extend(TensorDict({"source": torch.ones(20, 1)}, batch_size=[20]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # TorchRL 0.14 warns on a conflicting batch size
        batch = replay.sample()
    assert batch.shape == (8,)
    assert int((batch["source"] == 0).sum()) == 2  # round(0.25 * 8) offline transitions
    # the offline phase still samples its own default batch from the same storage
    assert run.offline_buffer.sample().shape == (8,)
    assert replay.buffer.offline_buffer.storage is run.offline_buffer.storage
