"""The Laplace fits of a learner that acts with a Laplace ensemble (Alg. 1 l. 9 and 17).

:class:`LaplaceRefits` is a mixin placed before a :class:`~torchrl_dual.recipe.Learner`
(``class IQLLALearner(LaplaceRefits, IQLLearner)``): it appends the offline ``laplace``
stage to the base learner's stages, counts the base learner's updates, refits once
``budget.laplace_refit_every`` of them have accumulated, checkpoints that count and logs
the ensemble's epistemic std of each collected batch. A fit sets ``σ̄`` (if the learner
gives one, :meth:`~LaplaceRefits.noise_std`), then fits Eq. (8) on
``D_offline ∪ D_online`` with the learner's per-sample weights. The learner builds the
acting ensemble over its actor with :meth:`~LaplaceRefits.act_with_ensemble` and sets
``laplace_weight_fn``. The checkpoint holds the base learner's modules and the
ensemble's own state (:class:`EnsembleOwnState`, without the tensors it shares with the
learner's ``actor``); a shared offline phase hands over the base learner's modules only.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn

from torchrl_dual.modules import LaplaceEnsembleActor, LastLayerActor, exploration_signals
from torchrl_dual.recipe.kits.build import env_kit
from torchrl_dual.recipe.o2o.learner import RunContext
from torchrl_dual.recipe.parts.networks import make_policy
from torchrl_dual.trainers.hooks import RefitSchedule


class LaplaceRefits:
    """Mixin: Eq. (8)'s posterior, fitted after the offline stages and refitted online.

    Fitted after the base learner's offline stages and refitted on ``D_offline ∪
    D_online`` every ``budget.laplace_refit_every`` updates.

    Attributes:
        actor (nn.Module): the base learner's actor, whose weights its modules save.
        ensemble (LaplaceEnsembleActor): the acting ensemble over a last-layer view of
            ``actor`` (:meth:`act_with_ensemble`).
        laplace_weight_fn (callable, optional): ``batch -> [B]`` weights of the actor
            loss whose Hessian Eq. (8) takes (e.g. ``WeightedMAPActorLoss.advantage_weights``);
            ``None``: uniform.
    """

    run: RunContext
    actor: nn.Module
    ensemble: LaplaceEnsembleActor
    laplace_weight_fn: Callable[[TensorDictBase], torch.Tensor] | None = None

    @property
    def refits(self) -> RefitSchedule:
        """The :class:`RefitSchedule` (made on first use from ``budget.laplace_refit_every``)."""
        if "_refits" not in self.__dict__:
            self._refits = RefitSchedule(self.run.settings.budget.laplace_refit_every)
        return self._refits

    def act_with_ensemble(self, actor: LastLayerActor) -> None:
        """Acts online with the Laplace ensemble over ``actor`` (Eq. 9), then Eq. (10)'s noise.

        The ensemble has ``M = laplace.num_samples`` and
        ``laplace.prior_precision``; the noise has ``λ = exploration.shift_weight``
        (0 without a transition model:
        :func:`~torchrl_dual.recipe.settings.algo_common.check_no_shift_weight`),
        followed by the env kit's ``action_projection``. Sets ``policy``,
        ``ensemble`` and ``exploration_policy``.
        """
        settings = self.run.settings
        self.policy = make_policy(
            settings.laplace,
            actor,
            self.run.env.action_spec,
            shift_weight=settings.exploration.shift_weight,
            action_projection=env_kit(settings).action_projection,
            device=settings.device,
        )
        self.ensemble = self.policy[0]
        self.exploration_policy = self.policy  # Eq. 9 + Eq. 10

    def modules(self) -> dict[str, Any]:
        """The base learner's (they save ``actor``) and the ensemble's own state."""
        return {**super().modules(), "ensemble": EnsembleOwnState(self.ensemble, self.actor)}

    def shared_modules(self) -> dict[str, Any]:
        """The base learner's offline phase; ``σ̄`` and the ``M`` draws are fitted after it."""
        return super().modules()

    def noise_std(self) -> torch.Tensor | None:
        """``σ̄`` per action dimension to fit with.

        ``None`` keeps the actor's own (DUAL learns it by Eq. 7).
        """
        return None

    def fit_laplace(self) -> None:
        """Fits Eq. (8) on ``run.all_transitions()`` with ``σ̄`` from :meth:`noise_std`.

        No posterior with ``num_samples=0`` (the ensemble then acts with the MAP
        action and ``σ̄`` only). Logs ``laplace/noise_std`` and
        ``laplace/prior_precision``.
        """
        actor, metrics = self.ensemble.actor, {}
        std = self.noise_std()
        with torch.no_grad():
            if std is not None:
                actor.log_std.copy_(std.log().clamp(actor.min_log_std, actor.max_log_std))
                metrics["noise_std"] = float(actor.std.mean())
            if self.ensemble.num_samples > 0:
                laplace = self.ensemble.fit_laplace(
                    self.run.all_transitions(), weight_fn=self.laplace_weight_fn
                )
                metrics["prior_precision"] = laplace.prior_precision
        self.run.log(metrics, self.run.updates, "laplace/")

    def refit(self) -> None:
        """Resets the count, then :meth:`fit_laplace`."""
        self.refits.reset()
        self.fit_laplace()

    def offline_stages(self) -> list:
        """The base learner's offline stages, then the Laplace fit (Alg. 1 line 9)."""
        return [*super().offline_stages(), ("laplace", self.refit)]

    def after_update(self) -> None:
        """The base learner's bookkeeping, then counts the update toward the next refit."""
        super().after_update()
        self.refits.count()

    def after_updates(self) -> None:
        """Alg. 1 line 17: refit once ``budget.laplace_refit_every`` updates accumulated."""
        if self.refits.due:
            self.refit()

    def batch_metrics(self, batch: TensorDictBase) -> dict[str, float]:
        """The base learner's batch metrics and the ensemble's exploration signals (Eq. 9-10)."""
        return {**super().batch_metrics(batch), **exploration_signals(batch)}

    def state_dict(self) -> dict[str, Any]:
        """The base learner's counters and the updates since the last refit."""
        return {**super().state_dict(), "updates_since_refit": self.refits.since}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores what :meth:`state_dict` returned."""
        super().load_state_dict(state)
        self.refits.since = state["updates_since_refit"]


class EnsembleOwnState:
    """The state of a Laplace ensemble without the actor's entries saved elsewhere.

    ``state_dict``/``load_state_dict`` without the entries of its actor that
    ``saved_elsewhere`` holds (the same tensors), so the checkpoint saves each weight
    once: the IQL actor's trunk and head (``iql_la``, saved by the IQL loss), the DDPM
    actor's score network and schedule (``diffql_la``, saved as ``actor``). What is left
    is the ensemble's own state: ``σ̄`` (``actor.log_std``), the actor's own buffers
    (e.g. its squash's box), the posterior and the ``M`` draws.

    Args:
        ensemble (nn.Module): the :class:`~torchrl_dual.modules.LaplaceEnsembleActor`.
        saved_elsewhere (nn.Module): the module whose tensors the ensemble's actor shares.
    """

    def __init__(self, ensemble: nn.Module, saved_elsewhere: nn.Module) -> None:
        self.ensemble = ensemble
        held = {id(value) for value in saved_elsewhere.state_dict(keep_vars=True).values()}
        self.shared = {
            f"actor.{name}"
            for name, value in ensemble.actor.state_dict(keep_vars=True).items()
            if id(value) in held
        }

    def state_dict(self) -> dict[str, Any]:
        """The ensemble's state dict without the entries held elsewhere."""
        state = self.ensemble.state_dict()
        return {name: value for name, value in state.items() if name not in self.shared}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Loads the ensemble's own entries; the shared ones stay as they are.

        Raises:
            RuntimeError: an entry of the ensemble's own is missing, or one is unexpected.
        """
        missing, unexpected = self.ensemble.load_state_dict(state, strict=False)
        if unexpected or set(missing) != self.shared:
            raise RuntimeError(
                f"ensemble state: missing {sorted(set(missing) - self.shared)}, "
                f"unexpected {sorted(unexpected)}"
            )
