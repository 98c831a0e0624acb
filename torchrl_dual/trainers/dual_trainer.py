"""``DUALTrainer``: Algorithm 1 on TorchRL's :class:`~torchrl.trainers.Trainer`.

Built on the plain :class:`~torchrl.trainers.Trainer` rather than TorchRL's
:class:`~torchrl.trainers.algorithms.OfflineToOnlineTrainer`, because the latter is a
:class:`~torchrl.trainers.algorithms.SACTrainer`: it does not take an
``optimization_stepper`` (DUAL steps two optimizers, IQL's critics then Eq. 7's actor)
and it anneals the offline share of each batch to zero, where DUAL keeps a fixed share.
What it adds over :class:`~torchrl.trainers.Trainer` for an offline-to-online buffer,
TorchRL's ``OfflineToOnlineReplayBufferHook``, is reused here without its annealing hook.

Registered, in this order (``Trainer`` runs each stage's ops in registration order):

* the :class:`~torchrl_dual.trainers.CriticActorStepper` (its optimizers in the
  checkpoint);
* ``policy``: DUAL's whole acting policy (Eq. 9's ensemble with its Laplace posterior and
  Eq. 10's :class:`~torchrl_dual.modules.ShiftAwareNoise`), so the checkpoint saves it;
* TorchRL's ``OfflineToOnlineReplayBufferHook`` (online data in the checkpoint);
* :class:`~torchrl_dual.trainers.OfflineStagesHook` at ``setup`` (Alg. 1, lines 1-9);
* :class:`~torchrl_dual.trainers.LaplaceRefitHook` (Eq. 8 on ``D_offline ∪ D_online``
  every ``refit_interval`` optimizer steps, Alg. 1 line 17), then TorchRL's
  ``UpdateWeights``, which pushes the refitted policy to the collector;
* :class:`~torchrl_dual.trainers.DUALSignalsLogHook` (``log_signals``: Eq. 9-10's
  signals of each collected batch) and, when given, an ``evaluation`` hook such as
  :class:`~torchrl_dual.trainers.NormalizedScoreLogHook` (its schedule in the checkpoint).

Build the collector with :func:`~torchrl_dual.trainers.dual_collector`: the posterior
does not exist before the offline stages run. ``tests/trainers/test_dual_trainer.py``
trains a toy run through :meth:`~torchrl.trainers.Trainer.train` and resumes it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.data import OfflineToOnlineReplayBuffer
from torchrl.trainers import OptimizationStepper, Trainer, UpdateWeights
from torchrl.trainers.algorithms.offline_to_online import OfflineToOnlineReplayBufferHook

from torchrl_dual._tensordict_patch import install as install_tensordict_patch
from torchrl_dual.trainers.hooks import LaplaceRefitHook, OfflineStagesHook
from torchrl_dual.trainers.logging_hooks import DUALSignalsLogHook

__all__ = ["DUALTrainer"]


class DUALTrainer(Trainer):
    """DUAL's offline stages, then online collection with critic-then-actor updates.

    Args:
        collector: a TorchRL collector running ``policy`` (see ``dual_collector``).
        policy: DUAL's acting policy, ``make_dual_policy(...)``: its first module is the
            :class:`~torchrl_dual.modules.LaplaceEnsembleActor` that is refitted.
        stepper: the critic-then-actor update, a
            :class:`~torchrl_dual.trainers.CriticActorStepper` or any TorchRL
            ``OptimizationStepper`` (then pass ``loss_module``, e.g. the ``DUALLoss``).
        replay_buffer: the offline-to-online buffer (fixed offline share per batch).
        offline_stages: ``(name, callable)`` pairs run once before collection.
        total_frames: online frames to collect.
        optim_steps_per_batch: updates per collected batch (the update-to-data ratio).
        refit_interval: optimizer steps between Laplace refits (Alg. 1 line 17).
        weight_fn: Eq. 7's per-sample weights for the refit, e.g.
            ``WeightedMAPActorLoss.advantage_weights``.
        batch_size: replay batch size (defaults to the buffer's).
        loss_module: the trainer's ``loss_module`` (saved in its checkpoint); defaults
            to the stepper's ``DUALLoss``.
        log_signals: log Eq. 9-10's signals of each collected batch
            (:class:`~torchrl_dual.trainers.DUALSignalsLogHook`). Defaults to ``True``.
        evaluation: a hook with a ``register(trainer)`` method run after each batch's
            updates, e.g. :class:`~torchrl_dual.trainers.NormalizedScoreLogHook`; none
            by default.
        **trainer_kwargs: the rest of :class:`~torchrl.trainers.Trainer`'s arguments
            (``save_trainer_file``, ``logger``, ``progress_bar``, ...).

    Examples:
        A toy run on Pendulum: a 40-step rollout stands in for the offline data set, and the
        offline stages are cut to three updates and the Laplace fit.

        >>> import torch
        >>> from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer
        >>> from torchrl.envs import GymEnv
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> from torchrl_dual.data import TRANSITION_KEYS
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> from torchrl_dual.modules import PlannerActor, TransitionModel, make_dual_policy
        >>> from torchrl_dual.objectives import DUALLoss, IQLCriticLoss
        >>> from torchrl_dual.trainers import CriticActorStepper, dual_collector
        >>> from torchrl_dual.transforms import PreviousTransition
        >>> env = GymEnv("Pendulum-v1").append_transform(PreviousTransition())
        >>> data = env.rollout(max_steps=40)
        >>> offline = ReplayBuffer(storage=LazyTensorStorage(40))
        >>> _ = offline.extend(data.select(*[key for key in TRANSITION_KEYS if key != "episode"]))
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 1, 2), num_steps=1, hidden=16, depth=1)
        >>> _ = model.normalizer.fit(data["observation"], data["action"])
        >>> actor = PlannerActor(model)
        >>> critic = IQLCriticLoss(
        ...     ValueOperator(MLP(in_features=4, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation", "action"]),
        ...     ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation"]))
        >>> loss = DUALLoss(actor, critic)
        >>> loss.make_value_estimator(gamma=0.99)
        >>> stepper = CriticActorStepper(
        ...     loss,
        ...     torch.optim.Adam(loss.critic_parameters()),
        ...     torch.optim.Adam(loss.actor_parameters()),
        ...     target_update=SoftUpdate(loss, tau=0.005))
        >>> policy = make_dual_policy(actor, env.action_spec, num_samples=3,
        ...                           transition_model=TransitionModel.frozen_copy(model))
        >>> weights = loss.actor_objective.advantage_weights
        >>> trainer = DUALTrainer(
        ...     collector=dual_collector(env, policy, frames_per_batch=20, total_frames=40),
        ...     policy=policy,
        ...     stepper=stepper,
        ...     replay_buffer=OfflineToOnlineReplayBuffer(
        ...         offline, online_capacity=100, offline_fraction=0.5, batch_size=16),
        ...     offline_stages=[
        ...         ("pretrain", lambda: [stepper.update(offline.sample(16)) for _ in range(3)]),
        ...         ("laplace", lambda: policy[0].fit_laplace([offline[:]], weight_fn=weights))],
        ...     total_frames=40, optim_steps_per_batch=2, refit_interval=4, weight_fn=weights,
        ...     progress_bar=False)
        >>> trainer.train()
        >>> trainer.collected_frames, trainer.offline_stages.done, trainer.laplace_refit.num_refits
        (40, ['pretrain', 'laplace'], 1)
    """

    def __init__(
        self,
        *,
        collector: Any,
        policy: Any,
        stepper: OptimizationStepper,
        replay_buffer: OfflineToOnlineReplayBuffer,
        offline_stages: Sequence[tuple[str, Callable[[], Any]]],
        total_frames: int,
        optim_steps_per_batch: int,
        refit_interval: int,
        weight_fn: Callable[[TensorDictBase], torch.Tensor] | None = None,
        batch_size: int | None = None,
        loss_module: Any | None = None,
        log_signals: bool = True,
        evaluation: Any | None = None,
        **trainer_kwargs: Any,
    ) -> None:
        install_tensordict_patch()  # TensorDictModule outputs without a sys.path scan each
        trainer_kwargs.setdefault("frame_skip", 1)
        super().__init__(
            collector=collector,
            total_frames=total_frames,
            optim_steps_per_batch=optim_steps_per_batch,
            loss_module=stepper.loss if loss_module is None else loss_module,
            optimization_stepper=stepper,
            **trainer_kwargs,
        )
        self.policy = policy
        self.register_module("policy", policy)
        OfflineToOnlineReplayBufferHook(replay_buffer, batch_size=batch_size).register(self)
        self.offline_stages = OfflineStagesHook(offline_stages)
        self.offline_stages.register(self)
        self.laplace_refit = LaplaceRefitHook(
            policy[0],
            lambda: [
                b[:] for b in (replay_buffer.offline_buffer, replay_buffer.online_buffer) if len(b)
            ],
            refit_interval,
            weight_fn=weight_fn,
        )
        # the refit is registered before the push, so no reordering is needed here
        self.laplace_refit._trainer = self
        self.register_module("laplace_refit", self.laplace_refit)
        self.register_op("post_steps", self.laplace_refit)
        UpdateWeights(collector, update_weights_interval=1).register(self)
        if log_signals:
            DUALSignalsLogHook().register(self)
        if evaluation is not None:  # after the refit and the push: it scores the new policy
            evaluation.register(self)
