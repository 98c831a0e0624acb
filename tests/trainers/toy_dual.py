"""A toy DUAL run on TorchRL's ``Trainer`` (Pendulum, tiny networks), shared by the tests."""

from __future__ import annotations

import torch
from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer
from torchrl.envs import GymEnv
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import SoftUpdate
from torchrl.trainers import Trainer, UpdateWeights
from torchrl.trainers.algorithms.offline_to_online import OfflineToOnlineReplayBufferHook

from torchrl_dual.data import TRANSITION_KEYS, validate_transitions
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import PlannerActor, TransitionModel, make_dual_policy
from torchrl_dual.objectives import DUALLoss, IQLCriticLoss
from torchrl_dual.trainers import (
    CriticActorStepper,
    DUALTrainer,
    LaplaceRefitHook,
    OfflineStagesHook,
    dual_collector,
)
from torchrl_dual.transforms import PreviousTransition

KEYS = [key for key in TRANSITION_KEYS if key != "episode"]


def toy_parts():
    """DUAL's parts at toy scale: policy, stepper, replay buffer and offline stages."""
    torch.manual_seed(0)
    env = GymEnv("Pendulum-v1").append_transform(PreviousTransition())
    env.set_seed(0)
    rollout = env.rollout(max_steps=40)
    rollout["episode"] = torch.zeros(40, dtype=torch.long)
    transitions = validate_transitions(rollout.select(*TRANSITION_KEYS))
    model = TrajectoryDiffusion(
        TrajectoryLayout(obs_dim=3, action_dim=1, horizon=2), num_steps=1, hidden=16, depth=1
    )
    model.normalizer.fit(transitions["observation"], transitions["action"])
    actor = PlannerActor(model)
    critic = IQLCriticLoss(
        ValueOperator(
            MLP(in_features=4, out_features=1, num_cells=[16]), ["observation", "action"]
        ),
        ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]), ["observation"]),
    )
    loss = DUALLoss(actor, critic, temperature=3.0)
    loss.make_value_estimator(gamma=0.99)
    stepper = CriticActorStepper(
        loss,
        torch.optim.Adam(loss.critic_parameters(), lr=3e-4),
        torch.optim.Adam(loss.actor_parameters(), lr=3e-4),
        target_update=SoftUpdate(loss, tau=0.005),
    )
    actor_loss = loss.actor_objective
    policy = make_dual_policy(
        actor, env.action_spec, transition_model=TransitionModel.frozen_copy(model), num_samples=3
    )
    offline = ReplayBuffer(storage=LazyTensorStorage(len(transitions)))
    offline.extend(transitions.select(*KEYS))
    replay = OfflineToOnlineReplayBuffer(
        offline, online_capacity=200, offline_fraction=0.5, batch_size=16
    )
    ensemble = policy[0]
    runs = {"pretrain": 0, "laplace_fit": 0}

    def pretrain():
        runs["pretrain"] += 1
        for _ in range(3):
            stepper.update(offline.sample(16))

    def laplace_fit():
        runs["laplace_fit"] += 1
        ensemble.fit_laplace([offline[:]], weight_fn=actor_loss.advantage_weights)

    stages = [("pretrain", pretrain), ("laplace_fit", laplace_fit)]
    return env, policy, stepper, replay, stages, runs, loss


def toy_trainer(save_file, *, total_frames: int = 40, refit_interval: int = 4, log=None):
    """A plain Trainer with DUAL's stepper and hooks; ``log`` records the post_steps order."""
    env, policy, stepper, replay, stage_list, runs, loss = toy_parts()
    offline, ensemble = replay.offline_buffer, policy[0]
    collector = dual_collector(env, policy, frames_per_batch=20, total_frames=total_frames)
    trainer = Trainer(
        collector=collector,
        total_frames=total_frames,
        frame_skip=1,
        optim_steps_per_batch=2,
        loss_module=loss,
        optimization_stepper=stepper,
        progress_bar=False,
        save_trainer_file=save_file,
        save_trainer_interval=1,
    )
    trainer.register_module("policy", policy)
    if log is not None:  # stands for the weight push, registered before the refit hook
        trainer.register_op("post_steps", lambda: log.append("push"))
    UpdateWeights(collector, update_weights_interval=1).register(trainer)
    OfflineToOnlineReplayBufferHook(replay, batch_size=16).register(trainer)
    stages = OfflineStagesHook(stage_list)
    stages.register(trainer)
    refit = LaplaceRefitHook(
        ensemble,
        lambda: [offline[:], replay.online_buffer[:]],
        refit_interval,
        weight_fn=loss.actor_objective.advantage_weights,
    )
    refit.register(trainer)
    if log is not None:
        fit = ensemble.fit_laplace

        def logged_fit(*args, **kwargs):
            log.append("refit")
            return fit(*args, **kwargs)

        ensemble.fit_laplace = logged_fit
    return trainer, runs, stages, refit


def toy_dual_trainer(save_file, *, total_frames: int = 40, **trainer_kwargs):
    """The same run through ``DUALTrainer`` (``trainer_kwargs``: its other arguments)."""
    env, policy, stepper, replay, stages, runs, loss = toy_parts()
    trainer = DUALTrainer(
        collector=dual_collector(env, policy, frames_per_batch=20, total_frames=total_frames),
        policy=policy,
        stepper=stepper,
        replay_buffer=replay,
        offline_stages=stages,
        total_frames=total_frames,
        optim_steps_per_batch=2,
        refit_interval=4,
        weight_fn=loss.actor_objective.advantage_weights,
        batch_size=16,
        progress_bar=False,
        save_trainer_file=save_file,
        save_trainer_interval=1,
        **trainer_kwargs,
    )
    return trainer, runs
