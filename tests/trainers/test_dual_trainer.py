"""DUALTrainer trains a toy DUAL run through TorchRL's Trainer.train() and resumes it."""

import torch

from tests.trainers.toy_dual import toy_dual_trainer


def test_dual_trainer_trains_and_resumes_its_offline_stages(tmp_path):
    trainer, runs = toy_dual_trainer(tmp_path / "trainer.pt")
    ensemble = trainer.policy[0]
    trainer.train()
    assert runs == {"pretrain": 1, "laplace_fit": 1}
    assert trainer.collected_frames == 40 and trainer._optim_count == 4
    assert trainer.laplace_refit.num_refits == 1
    assert len(trainer._modules["replay_buffer"].replay_buffer.online_buffer) == 40
    precision = ensemble.laplace.prior_precision.clone()

    resumed, runs2 = toy_dual_trainer(tmp_path / "trainer.pt", total_frames=60)
    resumed.load_from_file(tmp_path / "trainer.pt")
    assert resumed.offline_stages.done == ["pretrain", "laplace_fit"]
    torch.testing.assert_close(resumed.policy[0].laplace.prior_precision, precision)
    assert resumed.collected_frames == 40
    resumed.train()  # one more batch of 20 frames, no offline stage again
    assert runs2 == {"pretrain": 0, "laplace_fit": 0}
    assert resumed.collected_frames == 60 and resumed._optim_count == 6
    assert len(resumed._modules["replay_buffer"].replay_buffer.online_buffer) == 60
