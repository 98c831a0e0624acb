"""The refit schedule of a learner that acts with a Laplace ensemble (Alg. 1 l. 9 and 17).

:class:`LaplaceRefits` is a mixin placed before a :class:`~torchrl_dual.recipe.Learner`
(``class IQLLALearner(LaplaceRefits, IQLLearner)``): it appends the offline ``laplace``
stage to the base learner's stages, counts the base learner's updates, refits once
``budget.laplace_refit_every`` of them have accumulated, checkpoints that count and logs
the ensemble's epistemic std of each collected batch. The learner defines only
:meth:`LaplaceRefits.fit_laplace`, the fit itself.
"""

from __future__ import annotations

from typing import Any

from tensordict import TensorDictBase

from torchrl_dual.recipe.o2o_run import O2ORun


class LaplaceRefits:
    """Mixin: Eq. (8)'s posterior fitted after the base learner's offline stages and
    refitted on ``D_offline ∪ D_online`` every ``budget.laplace_refit_every`` updates."""

    run: O2ORun
    updates_since_refit: int = 0

    def fit_laplace(self) -> None:
        """(Re)fits the posterior on ``self.run.all_transitions()``."""
        raise NotImplementedError

    def refit(self) -> None:
        """Resets the count, then :meth:`fit_laplace`."""
        self.updates_since_refit = 0
        self.fit_laplace()

    def offline_stages(self) -> list:
        return [*super().offline_stages(), ("laplace", self.refit)]

    def update(self, batch: TensorDictBase) -> dict[str, float]:
        metrics = super().update(batch)
        self.updates_since_refit += 1
        return metrics

    def after_updates(self) -> None:
        """Alg. 1 line 17: refit once ``budget.laplace_refit_every`` updates accumulated."""
        if self.updates_since_refit >= self.run.cfg.budget.laplace_refit_every:
            self.refit()

    def batch_metrics(self, batch: TensorDictBase) -> dict[str, float]:
        epistemic = float(batch["epistemic_variance"].mean().sqrt())
        return {**super().batch_metrics(batch), "epistemic_std": epistemic}

    def state_dict(self) -> dict[str, Any]:
        return {**super().state_dict(), "updates_since_refit": self.updates_since_refit}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        self.updates_since_refit = state["updates_since_refit"]
