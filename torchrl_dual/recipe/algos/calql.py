"""The ``calql`` baseline: Cal-QL (Nakamoto et al. 2023) offline, then online.

A tanh-Gaussian MLP actor (the ``iql`` baseline's, same sizes) trained by SAC's actor
loss with automatic entropy tuning, on Cal-QL's twin Q networks
(:class:`~torchrl_dual.objectives.CalQLLoss`, the ``calql`` entry of ``CRITICS``:
TorchRL's ``CQLLoss`` whose conservative penalty bounds the policy Q-values from below
by the data's Monte-Carlo return). Everything else (data, budget, replay, UTD, evaluation)
is :class:`~torchrl_dual.recipe.O2ORun`'s.

**The bound** (``mc_return``) on ``D_offline`` and on each finished online episode:
:class:`~torchrl_dual.recipe.parts.mc_labels.MonteCarloLabels`.
"""

from __future__ import annotations

from tensordict import TensorDictBase

from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.algos.iql import make_iql_actor
from torchrl_dual.recipe.kits.build import projected_policy
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts.critics import make_critic
from torchrl_dual.recipe.parts.mc_labels import MonteCarloLabels


class CalQLLearner(Learner):
    """Cal-QL: one ``budget.offline_updates`` stage offline, then the same update online."""

    title = "Cal-QL"
    shared_stages = ("actor_critic",)  # offline_cache: shared by every online shift

    def __init__(self, run: RunContext) -> None:
        self.run = run
        settings = run.settings
        s = settings.actor
        self.actor = make_iql_actor(
            s, run.data.obs_dim, run.env.action_spec, device=settings.device
        )
        self.critic = make_critic(settings, run.data.obs_dim, run.data.action_dim, actor=self.actor)
        self.labels = MonteCarloLabels(run)  # D_offline's bound; D_online's per episode
        loss = self.critic.loss
        self.actor_optimizer = adam(
            [*loss.actor_network_params.values(True, True), loss.log_alpha], lr=s.lr
        )
        self.evaluation_policy = self.actor
        self.exploration_policy = projected_policy(settings, self.actor)

    def modules(self) -> dict:
        """The Cal-QL loss holds the actor, both Q, the target Q networks and ``log α``."""
        return {**self.critic.modules(), "actor_optimizer": self.actor_optimizer}

    def offline_stages(self) -> list:
        """One offline stage: ``budget.offline_updates`` actor-critic updates on D_offline."""
        return [("actor_critic", self.run.pretrain_updates)]

    def online_transitions(self, transitions: TensorDictBase) -> TensorDictBase:
        """The finished episodes among ``transitions``, labelled with Cal-QL's returns-to-go.

        The unfinished tail is held until its episode ends (:class:`MonteCarloLabels`).
        """
        return self.labels.online_transitions(transitions)

    def collector_started(self) -> None:
        """Ends the held episode at its last transition, as a new collector starts."""
        self.labels.cut()

    def update(self, batch: TensorDictBase) -> dict:
        """Cal-QL's update on one batch: critic, actor and ``log α`` steps, then the target update.

        The critics on TD + bounded penalty, the actor and ``log α`` on SAC's losses
        (which read the Q networks detached); one step of each optimizer, then the
        soft target update.
        """
        loss = self.critic.loss
        out = loss(batch)
        critic_loss = out["loss_qvalue"] + out["loss_cql"]
        if loss.with_lagrange:  # critic.lagrange_gap: the multiplier steps with the Q networks
            critic_loss = critic_loss + out["loss_alpha_prime"]
        self.critic.optimizer.zero_grad(set_to_none=True)
        self.actor_optimizer.zero_grad(set_to_none=True)
        (critic_loss + out["loss_actor"] + out["loss_alpha"]).backward()
        self.critic.optimizer.step()
        self.actor_optimizer.step()
        self.critic.target_updater.step()
        logged = {
            key: out[key].detach()
            for key in ("loss_qvalue", "loss_cql", "loss_actor", "alpha", "entropy", "bound_rate")
        }
        if loss.with_lagrange:
            logged["alpha_prime"] = loss.log_alpha_prime.detach().exp()
        return logged

    def state_dict(self) -> dict:
        """The held episode of the Monte-Carlo labels (checkpointed)."""
        return self.labels.state_dict()

    def load_state_dict(self, state: dict) -> None:
        """Restores the held episode of the Monte-Carlo labels."""
        self.labels.load_state_dict(state)
