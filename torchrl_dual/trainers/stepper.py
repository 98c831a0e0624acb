"""Alg. 1's critic-then-actor update as a TorchRL :class:`~torchrl.trainers.OptimizationStepper`.

DUAL trains its critic and Eq. (7)'s actor with two optimizers: one critic step, the
target-network update, then one actor step on the same batch, which reads the critic
just updated (Algorithm 1, lines 7-8 offline and 15-16 online). TorchRL's
:class:`~torchrl.trainers.DefaultOptimizationStepper` steps one optimizer on the sum of a
loss's ``loss_*`` entries; an :class:`~torchrl.trainers.OptimizationStepper` owns its
optimizers and can keep Alg. 1's order. This is the one place the package writes it: the
recipe's DUAL, Diff-QL (and DACER) and SO2 learners step their updates with it.

Nothing here reads a device value back to the host: the returned losses are detached
tensors (the trainer averages and logs them), so on a GPU the update queues without a
synchronisation.
"""

from __future__ import annotations

from typing import Any, Protocol

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.trainers import OptimizationStepper

__all__ = ["CriticActorLoss", "CriticActorStepper"]


class CriticActorLoss(Protocol):
    """What :class:`CriticActorStepper` steps: a critic's terms and an actor's loss.

    :class:`~torchrl_dual.objectives.DUALLoss` is one; the recipe's Diff-QL and SO2
    learners are others (their actor losses are Diff-QL's and SAC's).
    """

    def critic_loss(self, tensordict: TensorDictBase) -> tuple[dict[str, Any], dict[str, Any]]:
        """The critic's terms (summed into one backward pass) and metrics of a ``[B]`` batch."""

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict[str, Any]]:
        """The actor's loss and metrics of a ``[B]`` batch, on the critic just stepped."""


class CriticActorStepper(OptimizationStepper):
    """One critic step, the target update, then one actor step on the same batch.

    Args:
        loss (CriticActorLoss): the update's terms, e.g. a
            :class:`~torchrl_dual.objectives.DUALLoss`
            (:meth:`~torchrl_dual.objectives.DUALLoss.critic_loss`,
            :meth:`~torchrl_dual.objectives.DUALLoss.actor_loss`).
        critic_optimizer: steps the critic's parameters (``loss.critic_parameters()``).
        actor_optimizer: steps the actor's parameters (``loss.actor_parameters()``).

    Keyword Args:
        target_update: a TorchRL target updater (``SoftUpdate(loss, tau=...)``), stepped
            after each critic step; none by default.
        critic_max_grad_norm (float, optional): a gradient-norm clip of the critic step.
        actor_max_grad_norm (float, optional): a gradient-norm clip of the actor step
            (Diff-QL's).

    A batch stacked ``[k, B]`` (SO2's online phase) gets one critic step per ``[B]``
    batch, then the actor step on the last. Both optimizers and the target updater are in
    :meth:`state_dict`, so a trainer checkpoint (the stepper is a trainer module)
    restores them.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> from torchrl_dual.modules import LinearHeadActor
        >>> from torchrl_dual.objectives import DUALLoss, IQLCriticLoss
        >>> critic = IQLCriticLoss(
        ...     ValueOperator(MLP(in_features=5, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation", "action"]),
        ...     ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation"]))
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
        >>> loss = DUALLoss(actor, critic)
        >>> loss.make_value_estimator(gamma=0.99)
        >>> stepper = CriticActorStepper(
        ...     loss,
        ...     torch.optim.Adam(loss.critic_parameters(), lr=3e-4),
        ...     torch.optim.Adam(loss.actor_parameters(), lr=3e-4),
        ...     target_update=SoftUpdate(loss, tau=0.005))
        >>> batch = TensorDict({
        ...     "observation": torch.randn(8, 3), "action": torch.rand(8, 2) * 2 - 1,
        ...     "next": {"observation": torch.randn(8, 3), "reward": torch.randn(8, 1),
        ...              "done": torch.zeros(8, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(8, 1, dtype=torch.bool)}}, [8])
        >>> sorted(stepper.update(batch).keys())
        ['actor_std', 'log_prob', 'loss_actor', 'loss_qvalue', 'loss_value', 'weight_mean']
    """

    def __init__(
        self,
        loss: CriticActorLoss,
        critic_optimizer: torch.optim.Optimizer,
        actor_optimizer: torch.optim.Optimizer,
        *,
        target_update: Any | None = None,
        critic_max_grad_norm: float | None = None,
        actor_max_grad_norm: float | None = None,
    ) -> None:
        self.loss = loss
        self.critic_optimizer = critic_optimizer
        self.actor_optimizer = actor_optimizer
        self.target_update = target_update
        self.critic_max_grad_norm = critic_max_grad_norm
        self.actor_max_grad_norm = actor_max_grad_norm

    @staticmethod
    def _apply(
        optimizer: torch.optim.Optimizer, loss: torch.Tensor, max_grad_norm: float | None
    ) -> None:
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if max_grad_norm is not None:
            params = [p for group in optimizer.param_groups for p in group["params"]]
            torch.nn.utils.clip_grad_norm_(params, max_grad_norm)
        optimizer.step()

    def update(self, batch: TensorDictBase) -> TensorDictBase:
        """Runs Alg. 1 lines 7-8 / 15-16 on ``batch``.

        Returns every term and metric, detached (the last critic step's terms for a
        stacked batch).
        """
        for one in batch.unbind(0) if batch.ndim > 1 else (batch,):
            critic, critic_metrics = self.loss.critic_loss(one)
            self._apply(self.critic_optimizer, sum(critic.values()), self.critic_max_grad_norm)
            if self.target_update is not None:
                self.target_update.step()
        actor, metrics = self.loss.actor_loss(one)
        self._apply(self.actor_optimizer, actor, self.actor_max_grad_norm)
        return TensorDict({**critic, **critic_metrics, "loss_actor": actor, **metrics}).detach()

    def step(self, trainer: Any, sub_batch: TensorDictBase) -> TensorDictBase:
        """The :class:`~torchrl.trainers.OptimizationStepper` entry point."""
        return self.update(sub_batch)

    def state_dict(self) -> dict[str, Any]:
        """The state dicts of both optimizers and of the target updater (if it has one)."""
        state = {
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
        }
        if self.target_update is not None and hasattr(self.target_update, "state_dict"):
            state["target_update"] = self.target_update.state_dict()
        return state

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restores both optimizers and the target updater from :meth:`state_dict`.

        Args:
            state_dict (dict): ``{"critic_optimizer": ..., "actor_optimizer": ...,
                "target_update": ...}`` (the last only if saved).
        """
        self.critic_optimizer.load_state_dict(state_dict["critic_optimizer"])
        self.actor_optimizer.load_state_dict(state_dict["actor_optimizer"])
        if "target_update" in state_dict:
            self.target_update.load_state_dict(state_dict["target_update"])
