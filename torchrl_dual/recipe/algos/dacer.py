"""The ``dacer`` baseline: Diff-QL exploring with DACER's entropy regulator.

DACER (Wang et al. 2024, "Diffusion Actor-Critic with Entropy Regulator", NeurIPS;
reference code github.com/happy-yan/DACER-Diffusion-with-Online-RL) is an online
algorithm: a DDPM policy trained by ``−Q`` through the chain, exploring with

``a = clip(a_DDPM + noise_scale · α · ε)``,  ``ε ~ N(0, I)``,

where ``log α`` follows SAC's temperature rule toward a target entropy ``H̄`` and the
policy's entropy ``Ĥ`` is estimated by fitting a 3-component Gaussian mixture to ``K``
actions sampled per state (:mod:`~torchrl_dual.modules.exploration.entropy_regulator`,
:mod:`~torchrl_dual.modules.exploration.gmm_entropy`).

In the recipe, ``dacer`` is **Diff-QL's learner with DACER's regulator online**
(:class:`DACERLearner` subclasses :class:`~torchrl_dual.recipe.algos.diffql.DiffQLLearner`):

* **Training.** Diff-QL's, offline and online: the same ``DiffusionActor``,
  ``DiffQLActorLoss`` (``L_bc − η`` normalised Q-term) and IQL critics, so its offline
  phase is ``diffql``'s (the same weights for the same seed and keys). DACER's own
  actor loss (``−Q`` only) and distributional critic are not reproduced: the baseline
  isolates the exploration rule on the recipe's common actor-critic.
* **Acting.** Online, the chain's stochastic sample plus ``noise_scale · α · ε``,
  clamped to the action box, then the env kit's ``action_projection`` (Frozen-Lake's
  one-hot argmax), as ``diffql``. Evaluation is ``diffql``'s: the zero-latent chain
  under ``DETERMINISTIC``, no added noise (DACER's deterministic action drops the noise
  too, ``log α = −∞``).
* **Regulator.** Every ``dacer.entropy_every`` online updates (DACER: 10 000), ``Ĥ`` is
  the mean over the first ``dacer.num_states`` states of the update's batch (DACER: the
  whole batch) of the Gaussian-mixture entropy of ``dacer.num_samples`` exploration
  actions each (``K``; DACER: 200; noise and clamp included, before the projection),
  and one Adam step (``dacer.alpha_lr``; DACER: ``3e-2``) on
  ``L(log α) = −log α · (H̄ − Ĥ)`` raises ``α`` while ``Ĥ < H̄`` and lowers it above.
  ``H̄ = dacer.target_entropy``, by default DACER's ``−0.9 · dim(A)``; ``α`` starts at
  ``dacer.init_alpha`` (DACER: 3) and is not trained offline.

``log α`` and its Adam state are checkpointed (``exploration_noise``,
``alpha_optimizer``), as are the online update count and the last ``Ĥ``; a shared
offline phase (``offline_cache``) is Diff-QL's modules only, every ``dacer.*`` key being
an online key. ``online/alpha`` and ``online/entropy`` are logged after each block of
updates.
"""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential

from torchrl_dual.modules.exploration import (
    EntropyRegulatedNoise,
    dacer_target_entropy,
    sampled_entropy,
)
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.algos.diffql import DiffQLLearner
from torchrl_dual.recipe.o2o.learner import RunContext
from torchrl_dual.recipe.settings.baselines import DACERSettings
from torchrl_dual.recipe.settings.rules import dotted_keys


class DACERLearner(DiffQLLearner):
    """Diff-QL's training; online, DACER's entropy-regulated exploration noise."""

    title = "DACER (Diff-QL)"
    shared_stages = ("actor_critic",)  # offline_cache: Diff-QL's offline updates
    online_keys = tuple(dotted_keys(DACERSettings, "dacer"))

    def __init__(self, run: RunContext) -> None:
        super().__init__(run)
        d = self.settings.dacer
        target = d.target_entropy
        if target is None:
            target = dacer_target_entropy(run.data.action_dim)
        self.noise = EntropyRegulatedNoise(
            target, d.noise_scale, d.init_alpha, device=self.settings.device
        )
        self.alpha_optimizer = adam([self.noise.log_alpha], lr=d.alpha_lr)
        # what Ĥ is estimated of: the executed action before the env kit's projection
        self.noisy_actor = TensorDictSequential(self.actor, self.noise, self.clamp)
        self.exploration_policy = self.projected(self.noisy_actor)
        # evaluation_policy: Diff-QL's zero-latent chain (the noise is off under DETERMINISTIC)
        self.online_updates = 0
        self.entropy = float("nan")  # the last Ĥ

    def modules(self) -> dict[str, Any]:
        """Diff-QL's modules, the entropy-regulated noise and the temperature's optimizer."""
        return {
            **super().modules(),
            "exploration_noise": self.noise,
            "alpha_optimizer": self.alpha_optimizer,
        }

    def shared_modules(self) -> dict[str, Any]:
        """Diff-QL's offline phase; ``log α`` starts online from ``dacer.init_alpha``."""
        return super().modules()

    def regulate(self, observation: torch.Tensor) -> torch.Tensor:
        """Estimates the policy's entropy ``Ĥ``, then steps the temperature; returns ``Ĥ``.

        ``Ĥ`` on ``observation`` ``[B, S]`` (:func:`sampled_entropy` of the noisy,
        clamped actor, averaged over the states), then one Adam step on ``−log α ·
        (H̄ − Ĥ)``.
        """
        d = self.settings.dacer
        entropy = sampled_entropy(self.noisy_actor, observation, d.num_samples, d.num_components)
        self.alpha_optimizer.zero_grad(set_to_none=True)
        self.noise.alpha_loss(entropy).backward()
        self.alpha_optimizer.step()
        self.entropy = entropy.mean().detach()  # on the device: read back when logged
        return self.entropy

    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor | float]:
        """Diff-QL's update, plus online the entropy regulator's step.

        Online (once frames were collected) the regulator steps every
        ``dacer.entropy_every`` updates, starting with the first.
        """
        metrics = super().update(batch)
        if self.run.frames == 0:  # the offline phase: Diff-QL alone
            return metrics
        d = self.settings.dacer
        if self.online_updates % d.entropy_every == 0:
            self.regulate(batch["observation"][: d.num_states])
        self.online_updates += 1
        return {**metrics, "alpha": self.noise.alpha.detach(), "entropy": self.entropy}

    def state_dict(self) -> dict[str, Any]:
        """Diff-QL's counters, the online updates done and the last entropy estimate."""
        return {
            **super().state_dict(),
            "online_updates": self.online_updates,
            "entropy": float(self.entropy),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores what :meth:`state_dict` returned."""
        super().load_state_dict(state)
        self.online_updates = state["online_updates"]
        self.entropy = state["entropy"]
