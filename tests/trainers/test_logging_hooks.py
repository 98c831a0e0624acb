"""DUAL's logging hooks (torchrl_dual/trainers/logging_hooks.py) and their shared reduction
(torchrl_dual/modules/exploration_signals.py), inside TorchRL's Trainer."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from hydra.core.config_store import ConfigStore
from hydra.utils import instantiate
from omegaconf import OmegaConf
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer

from tests.trainers.toy_dual import toy_dual_trainer
from torchrl_dual.evaluation import evaluate_episodes
from torchrl_dual.modules import exploration_signals
from torchrl_dual.trainers import DUALSignalsLogHook, NormalizedScoreLogHook, register_configs


def test_exploration_signals_are_the_batch_means_of_eq_9_and_10_by_hand():
    gen = torch.Generator().manual_seed(0)
    variance = torch.rand(5, 3, 2, generator=gen)
    scale = 0.5 + torch.rand(5, 3, 2, generator=gen)
    shift = torch.rand(5, 3, 1, generator=gen)
    batch = TensorDict(
        epistemic_variance=variance,
        exploration_scale=scale,
        shift_distance=shift,
        batch_size=[5, 3],
    )
    signals = exploration_signals(batch)
    assert list(signals) == [
        "shift_distance",
        "epistemic_std",
        "epistemic_share",
        "exploration_std",
    ]
    assert signals["shift_distance"] == pytest.approx(shift.double().mean().item(), rel=1e-6)
    assert signals["epistemic_std"] == pytest.approx(
        variance.double().mean().sqrt().item(), rel=1e-6
    )
    share = variance.double().mean() / scale.double().square().mean()
    assert signals["epistemic_share"] == pytest.approx(share.item(), rel=1e-6)
    assert signals["exploration_std"] == pytest.approx(scale.double().mean().item(), rel=1e-6)
    # a policy without the ensemble (no epistemic key) gives no epistemic entry
    assert set(exploration_signals(batch.exclude("epistemic_variance"))) == {
        "shift_distance",
        "exploration_std",
    }


def test_the_trainer_logs_the_signals_of_each_batch_and_the_score_on_its_schedule(tmp_path):
    calls = []

    def evaluate():
        calls.append(1)
        return {"normalized_score": 10.0 * len(calls), "return": -1.0}

    score = NormalizedScoreLogHook(evaluate, interval=2)
    trainer, _ = toy_dual_trainer(tmp_path / "trainer.pt", total_frames=60, evaluation=score)
    trainer.train()  # 3 batches of 20 frames: the score after the 2nd only
    logged = trainer._log_dict
    for name in ("shift_distance", "epistemic_std", "epistemic_share", "exploration_std"):
        values = logged[f"dual/{name}"]
        assert len(values) == 3 and all(np.isfinite(values)), name
    assert all(v > 0 for v in logged["dual/epistemic_std"])  # the posterior was fitted
    assert logged["eval/normalized_score"] == [10.0] and len(calls) == 1
    assert score.batches == 3

    # resumed from TorchRL's checkpoint, the schedule goes on: batch 4 is scored
    resumed_score = NormalizedScoreLogHook(evaluate, interval=2)
    resumed, _ = toy_dual_trainer(
        tmp_path / "trainer.pt", total_frames=80, evaluation=resumed_score
    )
    resumed.load_from_file(tmp_path / "trainer.pt")
    assert resumed_score.batches == 3
    resumed.train()
    assert resumed._log_dict["eval/normalized_score"] == [20.0]


def test_without_log_signals_the_trainer_logs_no_signal(tmp_path):
    trainer, _ = toy_dual_trainer(tmp_path / "t.pt", total_frames=20, log_signals=False)
    trainer.train()
    assert not any(key.startswith("dual/") for key in trainer._log_dict)


def test_from_episodes_scores_the_mean_return_against_the_references():
    still = TensorDictModule(
        lambda o: torch.zeros(*o.shape[:-1], 1), in_keys=["observation"], out_keys=["action"]
    )

    def make_env():
        return gym.make("Pendulum-v1", max_episode_steps=7)

    hook = NormalizedScoreLogHook.from_episodes(
        make_env,
        still,
        3,
        random_return=-80.0,
        expert_return=-10.0,
        interval=1,
        observation_fn=lambda o: o,
        seed=4,
    )
    out = hook(None)
    mean = evaluate_episodes(make_env, still, 3, observation_fn=lambda o: o, seed=4).mean()
    assert out["eval/return"] == pytest.approx(mean)
    assert out["eval/normalized_score"] == pytest.approx(100 * (mean + 80.0) / 70.0)


def test_bad_interval_and_an_evaluation_without_the_score_name_the_fix():
    with pytest.raises(ValueError, match="interval must be >= 1"):
        NormalizedScoreLogHook(lambda: {}, interval=0)
    with pytest.raises(KeyError, match="without 'normalized_score'"):
        NormalizedScoreLogHook(lambda: {"return": 1.0}, interval=1)(None)
    assert DUALSignalsLogHook()(TensorDict(batch_size=[3])) is None


def test_the_stored_offline_to_online_buffer_samples_its_fixed_offline_share():
    register_configs()
    node = ConfigStore.instance().repo["replay_buffer"]["offline_to_online.yaml"].node
    cfg = OmegaConf.structured(node)
    offline = ReplayBuffer(storage=LazyTensorStorage(100))
    offline.extend(TensorDict(observation=torch.zeros(100, 2), batch_size=[100]))
    buffer = instantiate(
        cfg, online_capacity=50, batch_size=40, offline_fraction=0.25, _partial_=True
    )(offline_dataset=offline)
    assert isinstance(buffer, OfflineToOnlineReplayBuffer)
    buffer.extend(TensorDict(observation=torch.ones(50, 2), batch_size=[50]))
    batch = buffer.sample()
    assert batch.shape == (40,)
    assert int((batch["observation"][:, 0] == 0).sum()) == 10  # 0.25 of 40 from D_offline
