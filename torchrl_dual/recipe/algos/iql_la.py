"""The ``iql_la`` baseline: "IQL + LA", the paper's Laplace recipe on IQL's plain actor.

Everything IQL does stays as in :mod:`~torchrl_dual.recipe.algos.iql` (the learner is a
subclass of :class:`~torchrl_dual.recipe.IQLLearner`): the data, budget, critics, the
MLP actor (``actor.distribution``, ``gaussian`` by default as ``algo=iql``) and its
advantage-weighted regression (AWR) update, offline and online, the replay and the
evaluation. What changes is how it acts online:

* **Actor.** :meth:`~torchrl_dual.modules.LinearHeadActor.from_actor` shares the IQL
  actor's weights: the trunk ``φ(s)`` is its MLP without the last layer, the head is
  the last ``nn.Linear`` (its ``loc`` half for the ``TanhNormal``) and the squash is
  the map onto the action box, ``c + r tanh(u)``.
* **Posterior (Eq. 8).** Over the head ``u(s) = W φ(s) + b``, with IQL's AWR weights
  ``w = min(exp(β (Q − V)), 100)`` (``actor.temperature``; ``Q`` the minimum of the
  target twin Q networks, as ``IQLLoss``) on ``D_offline ∪ D_online``.
  ``gaussian`` (``N(c + r tanh(u), σ²)``): the Gauss-Newton Hessian through the tanh,
  one Gram matrix per action dimension ``G_j = Σ_i w_i J_ij² φ̃_i φ̃_iᵀ / σ_j²`` with
  ``J_ij = r_j (1 − tanh²(u_ij))`` (exact at zero residual; tested against autograd).
  ``tanh_normal``: IQL's loss ``−w log TanhNormal(a; loc(s), scale(s))`` is a weighted
  Gaussian regression of ``atanh(a)`` on ``loc(s)`` (the tanh Jacobian does not depend
  on the weights), so ``Σ_i w_i φ̃_i φ̃_iᵀ / σ̄²`` is its exact Hessian.
* **σ̄.** By default (``laplace.noise_std=iql``) each fit sets
  ``σ̄_a = sqrt(mean_D scale_a(s)²)``, the root-mean-square of the IQL actor's own std
  on the fit data (clamped to ``[1e-3, 2]`` by
  :class:`~torchrl_dual.modules.LastLayerActor`): the posterior uses the noise level
  IQL learned, and Eq. 9's aleatoric term is IQL's own exploration width. For
  ``gaussian`` that std is state-independent and in action units. For ``tanh_normal``
  it is the pre-tanh ``scale(s)`` (the homoscedastic ``σ̄`` is then an approximation);
  it is large where the data's actions sit on the box's faces (``atanh`` of them is
  large): on PointMaze it measured 4.7 after 500 updates and 2.6-2.9 after 2000, so
  ``σ̄`` sits at the clamp ``2``. A number (``laplace.noise_std=0.3``, DUAL's
  ``init_std``) fixes ``σ̄`` instead.
* **Acting (Eq. 9-10).** Each sub-policy acts ``a_m = TanhSquash(W_m φ(s) + b_m)``; the
  ensemble's mean and variance are over these ``M`` actions (``laplace.num_samples``),
  then :class:`~torchrl_dual.modules.ShiftAwareNoise` draws ``a ∼ N(μ, σ²)`` with
  ``λ = 0``: the plain actor has no transition model, so there is no ``ŝ_t`` (the
  config refuses ``exploration.shift_weight > 0``). The env kit's ``action_projection``
  follows (Frozen-Lake's one-hot argmax).
* **Refits.** Every ``budget.laplace_refit_every`` updates, as DUAL (Alg. 1 l. 17).
* **Evaluation.** IQL's own deterministic action (the Gaussian's mean, or the
  ``TanhNormal``'s ``tanh(loc)`` on the box: the IQL actor itself), exactly as ``algo=iql``, so the two baselines are
  scored by the same rule and differ only in how they explore. It equals the ensemble's
  MAP mean under ``DETERMINISTIC`` up to TorchRL's ``SafeTanh`` clamp (tested).
"""

from __future__ import annotations

import torch

from torchrl_dual import LinearHeadActor, WeightedMAPActorLoss
from torchrl_dual.recipe.algos.iql import IQLLearner
from torchrl_dual.recipe.o2o.learner import RunContext
from torchrl_dual.recipe.parts.laplace_refits import LaplaceRefits

IQL_MAX_WEIGHT = 100.0
"""TorchRL ``IQLLoss``'s clip of ``exp(β (Q − V))`` (fixed in its ``actor_loss``)."""


class IQLLALearner(LaplaceRefits, IQLLearner):
    """IQL + LA: IQL's learner, acting online with the Laplace ensemble of its actor.

    Fitted with ``σ̄`` = :meth:`noise_std` and IQL's AWR weights every
    ``budget.laplace_refit_every`` updates (:class:`LaplaceRefits`).
    """

    title = "IQL + LA"
    shared_stages = ("actor_critic",)  # offline_cache: IQL's offline updates only
    online_keys = (  # read only by the laplace stage and the online phase
        "laplace.num_samples",
        "laplace.prior_precision",
        "laplace.posterior_temperature",
        "laplace.noise_std",
        "exploration.shift_weight",
    )

    def __init__(self, run: RunContext) -> None:
        super().__init__(run)
        self.head_actor = LinearHeadActor.from_actor(self.actor)  # shared weights, tanh box
        # only its advantage weights are used (Eq. 8's Hessian); IQLLoss trains the actor
        self.laplace_weight_fn = WeightedMAPActorLoss.from_iql(
            self.head_actor,
            self.critic.loss,
            weighting="advantage",
            temperature=self.settings.actor.temperature,
            max_weight=IQL_MAX_WEIGHT,
        ).advantage_weights
        self.act_with_ensemble(self.head_actor)  # Eq. 9 + Eq. 10 with λ = 0
        # evaluation_policy: IQLLearner's, the IQL actor's deterministic tanh(loc)
        # modules(): IQL's (the loss holds the actor) and the ensemble's own state

    @torch.no_grad()
    def noise_std(self) -> torch.Tensor:
        """``σ̄`` per action dimension, set before each fit.

        ``laplace.noise_std`` if it is a number, else (``iql``) ``σ̄_a = sqrt(mean_D
        scale_a(s)²)``, the IQL actor's std (pre-tanh for ``tanh_normal``), root
        mean square over ``D_offline ∪ D_online``.
        """
        fixed = self.run.settings.laplace.noise_std
        if fixed != "iql":
            return torch.full_like(self.head_actor.log_std, float(fixed))
        loc_scale = self.actor.module[0]  # observation -> loc, scale
        total, count = 0.0, 0
        for batch in self.run.all_transitions():
            scale = loc_scale(batch.select("observation"))["scale"]
            total, count = total + scale.square().sum(0), count + scale.shape[0]
        return (total / count).sqrt()
