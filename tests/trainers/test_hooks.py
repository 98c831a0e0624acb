"""DUAL's hooks and stepper inside a real TorchRL ``Trainer`` (toy Pendulum run)."""

import torch

from tests.trainers.toy_dual import toy_trainer


def test_trainer_runs_offline_stages_refits_before_the_push_and_resumes(tmp_path):
    log = []
    trainer, runs, stages, refit = toy_trainer(tmp_path / "trainer.pt", log=log)
    trainer.train()
    assert runs == {"pretrain": 1, "laplace_fit": 1}
    assert stages.done == ["pretrain", "laplace_fit"]
    # 2 batches x 2 optimizer steps, refit every 4 steps: one refit, after the 2nd batch
    assert refit.num_refits == 1 and refit.last_refit_step == 4
    # the offline fit at setup, then per batch: the refit (after 4 steps) ran ahead of the
    # push registered before it (register_before_weight_update)
    assert log == ["refit", "push", "refit", "push"]
    saved_policy = {
        k: v.clone()
        for k, v in trainer._modules["policy"].state_dict().items()
        if torch.is_tensor(v) and v.is_floating_point()
    }
    assert saved_policy

    resumed, runs2, stages2, refit2 = toy_trainer(tmp_path / "trainer.pt", total_frames=60)
    resumed.load_from_file(tmp_path / "trainer.pt")
    assert stages2.done == ["pretrain", "laplace_fit"]
    assert refit2.last_refit_step == 4
    resumed_policy = resumed._modules["policy"].state_dict()
    for key, value in saved_policy.items():  # the trained weights and the fitted posterior
        torch.testing.assert_close(resumed_policy[key], value)
    resumed.train()
    assert runs2 == {"pretrain": 0, "laplace_fit": 0}  # finished stages are not redone


def test_stepper_steps_critic_then_actor_and_returns_tensors(tmp_path):
    trainer, _, _, _ = toy_trainer(tmp_path / "t.pt")
    stepper = trainer.optimization_stepper
    critic_before = [p.clone() for g in stepper.critic_optimizer.param_groups for p in g["params"]]
    actor_before = [p.clone() for g in stepper.actor_optimizer.param_groups for p in g["params"]]
    batch = trainer._modules["replay_buffer"].replay_buffer.offline_buffer.sample(16)
    out = stepper.step(trainer, batch)
    losses = {"loss_qvalue", "loss_value", "loss_actor"}  # DUALLoss's terms, then Eq. 7's metrics
    assert set(out.keys()) == losses | {"weight_mean", "log_prob", "actor_std"}
    assert all(torch.is_tensor(v) and not v.requires_grad for v in out.values())
    params = [p for g in stepper.critic_optimizer.param_groups for p in g["params"]]
    assert any(not torch.equal(a, b) for a, b in zip(critic_before, params, strict=True))
    params = [p for g in stepper.actor_optimizer.param_groups for p in g["params"]]
    assert any(not torch.equal(a, b) for a, b in zip(actor_before, params, strict=True))
    state = stepper.state_dict()
    assert set(state) >= {"critic_optimizer", "actor_optimizer", "target_update"}
    stepper.load_state_dict(state)
