"""The ``edis`` baseline: EDIS, as the DUAL paper runs it.

Liu et al. 2024, "Energy-Guided Diffusion Sampling for Offline-to-Online Reinforcement
Learning" (the DUAL paper's Appendix, "EDIS"; Section 2.2; Algorithm 1 line 14).

* **Offline.** The trajectory planner is pre-trained on ``D_offline`` with ``L_VLB``
  (Eq. 3), exactly as DUAL's (``planner.*`` keys, ``budget.planner_updates``, H = 8,
  N = 32); the actor-critic is the recipe's IQL (:class:`~torchrl_dual.recipe.IQLLearner`:
  TorchRL ``IQLLoss``, tanh-Gaussian MLP actor, the same critics and
  ``budget.offline_updates``).
* **Online.** IQL collects and fine-tunes as ``algo=iql``; every ``augment.every``
  updates a :class:`~torchrl_dual.recipe.parts.planner_augment.PlannerAugmenter` round refits
  the energy guider (offline vs online windows) and the reward model, and adds guided
  planner transitions from ``p_offline(τ)·e^{−ε(τ)}`` to ``D_online``, from which the
  actor-critic then samples like from collected data.

Not reproduced: EDIS's contrastive energy prediction (a classifier of noisy windows gives
the guidance here, see :mod:`torchrl_dual.diffusion.guidance`), its diffusion of rewards
and terminals inside the window (a reward model labels the transitions, see
:class:`~torchrl_dual.modules.RewardModel`) and its separate state/transition guiders.
"""

from __future__ import annotations

from typing import Any

from torchrl_dual.recipe.algos.iql import IQLLearner
from torchrl_dual.recipe.o2o.learner import RunContext
from torchrl_dual.recipe.parts import networks
from torchrl_dual.recipe.parts.planner_augment import (
    PlannerAugmenter,
    augment_capacity,
)
from torchrl_dual.recipe.parts.planner_stage import (
    offline_windows,
    pretrain_planner,
)


class EDISLearner(IQLLearner):
    """IQL plus the planner offline and planner augmentation online."""

    title = "EDIS"
    shared_stages = ("planner", "actor_critic")  # offline_cache: every online shift
    online_keys = ("augment",)

    def __init__(self, run: RunContext) -> None:
        super().__init__(run)
        settings = run.settings
        self.planner = networks.make_planner(settings.planner, run.data, settings.device)
        self.planner_windows = offline_windows(settings, run.data, settings.planner.batch_size)
        self.augmenter = PlannerAugmenter(run, self.planner)
        self.extra_online_capacity = augment_capacity(settings)

    def shared_modules(self) -> dict[str, Any]:
        """IQL's modules and the planner: what the shared offline phase hands over."""
        return {**super().modules(), "planner": self.planner}

    def modules(self) -> dict[str, Any]:
        """The shared modules and the augmenter's (its guide, reward model and their optimizers)."""
        return {**self.shared_modules(), **self.augmenter.modules()}

    def offline_stages(self) -> list:
        """The planner's pre-training, then IQL's offline stages."""
        return [("planner", self.pretrain_planner), *super().offline_stages()]

    def pretrain_planner(self) -> None:
        """``budget.planner_updates`` ``L_VLB`` steps on ``D_offline`` windows (Eq. 3)."""
        pretrain_planner(self.run, self.planner, self.planner_windows)

    def after_updates(self) -> None:
        """Algorithm 1 line 14: a planner augmentation round when due."""
        self.augmenter.after_updates()

    def state_dict(self) -> dict[str, Any]:
        """IQL's counters and the augmenter's."""
        return {**super().state_dict(), "augment": self.augmenter.state_dict()}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores what :meth:`state_dict` returned."""
        super().load_state_dict(state)
        self.augmenter.load_state_dict(state["augment"])
