"""The ``so2`` baseline: SO2 (Zhang et al. 2024) with OFF2ON's balanced replay.

A tanh-Gaussian MLP actor (the ``iql`` baseline's, same sizes) trained by SAC's actor
loss at a fixed ``α = critic.entropy_coef``, ``E[α·log π(ã|s) − min_k Q_k(s, ã)]`` with
``ã ∼ π(·|s)`` reparameterised, on SO2's Q ensemble (the ``so2`` entry of ``CRITICS``,
:class:`~torchrl_dual.objectives.SO2QLoss`). As in the authors' code (``opendilab/SO2``):

* offline, SAC-N: the target is the ensemble's minimum at an unperturbed next action, one
  critic and one actor step per update (``budget.offline_updates`` of them);
* online, SO2: each member's own target at the noise-smoothed next action, and
  ``critic.online_steps_per_update`` critic steps (each on its own batch) per actor step;
  with ``online.utd_ratio=1`` that is SO2's 10 critic updates per environment step and one
  actor update per 10 critic updates.

``algo/so2.yaml`` selects ``critic=so2`` and ``replay=balanced`` (OFF2ON's density-ratio
priorities, :mod:`torchrl_dual.recipe.o2o.replays`), the paper's "SO2 + OFF2ON" base critic.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.algos.iql import make_iql_actor
from torchrl_dual.recipe.kits.build import projected_policy
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts.critics import make_critic
from torchrl_dual.trainers.stepper import CriticActorStepper


class SO2Learner(Learner):
    """SO2: SAC-N offline, then SO2's critic updates online.

    Online: SO2's smoothed per-member targets and ``k`` critic steps per actor step.
    """

    title = "SO2"
    shared_stages = ("actor_critic",)  # offline_cache: shared by every online shift

    def __init__(self, run: RunContext) -> None:
        self.run = run
        settings = run.settings
        s = settings.actor
        self.actor = make_iql_actor(
            s, run.data.obs_dim, run.env.action_spec, return_log_prob=True, device=settings.device
        )
        self.critic = make_critic(settings, run.data.obs_dim, run.data.action_dim, actor=self.actor)
        self.online_batches_per_update = self.critic.online_steps_per_update
        self.actor_optimizer = adam(self.actor.parameters(), lr=s.lr)
        self.alpha = settings.critic.entropy_coef
        self.stepper = CriticActorStepper(
            self, self.critic.optimizer, self.actor_optimizer,
            target_update=self.critic.target_updater,
        )  # fmt: skip
        self.evaluation_policy = self.actor
        self.exploration_policy = projected_policy(settings, self.actor)

    def modules(self) -> dict:
        """The actor (the critic loss does not hold it), the Q ensemble and its targets."""
        return {
            "actor": self.actor,
            **self.critic.modules(),
            "actor_optimizer": self.actor_optimizer,
        }

    def offline_stages(self) -> list:
        """One offline stage: ``budget.offline_updates`` SAC-N updates on D_offline."""
        return [("actor_critic", self.run.pretrain_updates)]

    def critic_loss(self, batch: TensorDictBase) -> tuple[dict, dict]:
        """The ensemble's TD terms (SAC-N offline, SO2's smoothed targets online)."""
        return self.critic.loss.critic_terms(batch), {}

    def actor_loss(self, batch: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """SAC's actor loss and the policy's entropy estimate.

        ``E[α·log π(ã|s) − min_k Q_k(s, ã)]`` and ``{"entropy": E[−log π(ã|s)]}``;
        ``ã`` is a reparameterised sample; the ensemble's weights are read detached.
        """
        observation = batch["observation"]
        dist = self.actor.get_dist(batch.select("observation"))
        action = dist.rsample()
        log_prob = dist.log_prob(action)
        q = self.critic.loss.q_value(observation, action)
        return (self.alpha * log_prob - q).mean(), {"entropy": -log_prob.mean().detach()}

    def collector_started(self) -> None:
        """Online from here: the critic takes SO2's targets (SAC-N's until then)."""
        self.critic.set_phase(online=True)

    def update(self, batch: TensorDictBase) -> dict:
        """Critic steps, one per batch of a stacked ``[k, B]``, then an actor step on the last."""
        return dict(self.stepper.update(batch).items())
