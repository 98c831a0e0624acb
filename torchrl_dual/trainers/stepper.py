"""Critic-then-actor optimization step for TorchRL's :class:`~torchrl.trainers.Trainer`.

DUAL trains IQL's critics (expectile value loss and Q loss) and Eq. (7)'s weighted-MAP
actor with two optimizers: one critic step, the target-network update, then one actor
step on the same batch (Algorithm 1, lines 6-8 offline and 13-15 online). TorchRL's
:class:`~torchrl.trainers.DefaultOptimizationStepper` steps one optimizer on the sum of a
single loss module's ``loss_*`` entries, so it cannot express this; an
:class:`~torchrl.trainers.OptimizationStepper` owns its optimizers and can.

Nothing here reads a device value back to the host: the returned losses are detached
tensors (the trainer averages and logs them), so on a GPU the update queues without a
synchronisation.

Example:
    >>> import torch
    >>> from torch import nn
    >>> from tensordict import TensorDict
    >>> from torchrl_dual.trainers import CriticActorStepper
    >>> critic, actor = nn.Linear(2, 1), nn.Linear(2, 1)
    >>> stepper = CriticActorStepper(
    ...     critic_loss_fn=lambda b: critic(b["observation"]).pow(2).mean(),
    ...     actor_loss_fn=lambda b: {"loss_actor": actor(b["observation"]).pow(2).mean()},
    ...     critic_optimizer=torch.optim.SGD(critic.parameters(), lr=0.1),
    ...     actor_optimizer=torch.optim.SGD(actor.parameters(), lr=0.1),
    ... )
    >>> out = stepper.step(None, TensorDict(observation=torch.ones(4, 2), batch_size=[4]))
    >>> sorted(out.keys())
    ['loss_actor', 'loss_critic']
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.trainers import OptimizationStepper

__all__ = ["CriticActorStepper", "iql_critic_loss"]


def iql_critic_loss(iql: Any) -> Callable[[TensorDictBase], torch.Tensor]:
    """IQL's critic objective of a TorchRL :class:`~torchrl.objectives.IQLLoss`.

    The sum of its Q loss (TD regression to ``r + γ V(s')``) and its expectile value loss,
    without the AWR actor term (DUAL's actor loss is Eq. 7 instead).
    """

    def loss(batch: TensorDictBase) -> torch.Tensor:
        return iql.qvalue_loss(batch)[0] + iql.value_loss(batch)[0]

    return loss


class CriticActorStepper(OptimizationStepper):
    """One critic step, the target update, then one actor step on the same batch.

    Args:
        critic_loss_fn: batch -> scalar critic loss (e.g. :func:`iql_critic_loss`).
        actor_loss_fn: batch -> mapping with ``"loss_actor"`` (e.g. a
            :class:`~torchrl_dual.objectives.WeightedMAPActorLoss`, Eq. 7).
        critic_optimizer: the optimizer of the critic's parameters.
        actor_optimizer: the optimizer of the actor's parameters.
        target_update: optional TorchRL target updater (``SoftUpdate``/``HardUpdate``),
            stepped after the critic step.
        max_grad_norm: optional gradient-norm clip applied to both steps.

    Both optimizers and the target updater's state are in :meth:`state_dict`, so a
    trainer checkpoint (the stepper is registered as a trainer module) restores them.
    """

    def __init__(
        self,
        critic_loss_fn: Callable[[TensorDictBase], torch.Tensor],
        actor_loss_fn: Callable[[TensorDictBase], Mapping[str, torch.Tensor]],
        critic_optimizer: torch.optim.Optimizer,
        actor_optimizer: torch.optim.Optimizer,
        target_update: Any | None = None,
        max_grad_norm: float | None = None,
    ) -> None:
        self.critic_loss_fn = critic_loss_fn
        self.actor_loss_fn = actor_loss_fn
        self.critic_optimizer = critic_optimizer
        self.actor_optimizer = actor_optimizer
        self.target_update = target_update
        self.max_grad_norm = max_grad_norm

    def _apply(self, optimizer: torch.optim.Optimizer, loss: torch.Tensor) -> None:
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.max_grad_norm is not None:
            params = [p for group in optimizer.param_groups for p in group["params"]]
            torch.nn.utils.clip_grad_norm_(params, self.max_grad_norm)
        optimizer.step()

    def update(self, batch: TensorDictBase) -> TensorDictBase:
        """One critic-then-actor update; returns the detached losses (no host read)."""
        critic_loss = self.critic_loss_fn(batch)
        self._apply(self.critic_optimizer, critic_loss)
        if self.target_update is not None:
            self.target_update.step()
        actor_loss = self.actor_loss_fn(batch)["loss_actor"]
        self._apply(self.actor_optimizer, actor_loss)
        return TensorDict(
            loss_critic=critic_loss.detach(), loss_actor=actor_loss.detach(), batch_size=[]
        )

    def step(self, trainer: Any, sub_batch: TensorDictBase) -> TensorDictBase:
        """The :class:`~torchrl.trainers.OptimizationStepper` entry point."""
        return self.update(sub_batch)

    def state_dict(self) -> dict[str, Any]:
        state = {
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
        }
        if self.target_update is not None and hasattr(self.target_update, "state_dict"):
            state["target_update"] = self.target_update.state_dict()
        return state

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.critic_optimizer.load_state_dict(state_dict["critic_optimizer"])
        self.actor_optimizer.load_state_dict(state_dict["actor_optimizer"])
        if "target_update" in state_dict:
            self.target_update.load_state_dict(state_dict["target_update"])
