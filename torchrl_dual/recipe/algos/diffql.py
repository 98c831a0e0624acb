"""The ``diffql`` and ``diffql_la`` baselines: Diff-QL (Wang et al. 2023) and "Diff-QL w LA".

**Diff-QL** ("Diffusion policies as an expressive policy class for offline RL"): the
policy is TorchRL's :class:`~torchrl.modules.DiffusionActor`, an ``N``-step DDPM over the
action (``actor.num_steps = 5`` as in the paper) with Wang et al.'s variance-preserving
schedule ``β_t = 1 − exp(−β_min/N − (β_max − β_min)(2t − 1)/(2N²))`` (``β_min = 0.1``,
``β_max = 10``; TorchRL's default linear ``1e-4 … 0.02`` schedule would leave
``ᾱ_N ≈ 0.95`` at ``N = 5``, far from noise). It is trained with
:class:`~torchrl_dual.objectives.diffql_actor_loss.DiffQLActorLoss`,

``L(θ) = L_bc(θ) − η · mean Q(s, a_π) / mean |Q(s, a_π)|``,

``L_bc`` TorchRL's :class:`~torchrl.objectives.DiffusionBCLoss` (ε-prediction on the
batch actions) and ``a_π`` a sample of the actor's stochastic chain with gradients
through all ``N`` denoising steps, clamped to the action box (Wang et al. clip it too);
the normaliser ``mean |Q|`` is detached (Wang et al.'s). ``Q`` is ``min_k Q_k`` of the
twin critics with their weights detached, so the Q-term trains the actor only.

**Critic.** Diff-QL's own critic is a TD3-style double Q trained on the actor's actions;
the recipe keeps its critic table instead: the SAME IQL critics as ``dual`` and ``iql``
(``CRITICS["iql"]``, built without an actor, as :class:`~torchrl_dual.recipe.DualLearner`
does), so every algorithm is compared on one critic. Not reproduced either: Wang et al.'s
EMA copy of the actor, their sinusoidal time embedding (the TorchRL score network reads
the raw step index) and their Q-softmax action selection at evaluation.

**Acting.** Online, ``diffql`` collects with the actor's stochastic DDPM samples
(``ExplorationType.RANDOM``), clamped to the action box and projected by the env kit's
``action_projection`` (Frozen-Lake's one-hot argmax). It is evaluated deterministically:
under ``ExplorationType.DETERMINISTIC`` TorchRL's ``DiffusionActor`` runs the chain from
the zero latent ``x_N = 0`` without injected noise (a repeatable action, not a sample).

**Diff-QL w LA** (``diffql_la``, the paper's Fig. 4(c), ``M = 5``): the same training;
acting goes through :class:`~torchrl_dual.modules.DDPMLastStepActor` (the zero-latent
chain with the score network's final ``nn.Linear`` as the Laplace layer), the
:class:`~torchrl_dual.modules.LaplaceEnsembleActor` of Eq. (9) and
:class:`~torchrl_dual.modules.ShiftAwareNoise`, assembled by
:func:`~torchrl_dual.modules.make_dual_policy` with ``λ = 0``: Diff-QL has no transition
model ``ŝ_t``, so ``exploration.shift_weight > 0`` is a config error. The last-layer
posterior (Eq. 8) is fitted after the offline phase and refitted every
``budget.laplace_refit_every`` updates on ``D_offline ∪ D_online`` with the advantage
weights ``min(exp(β (Q − V)), w_max)`` of the IQL critics. Diff-QL trains no ``σ̄``, so
each fit first sets the Gaussian width ``σ̄`` of Eq. (7-9) to its maximiser given the
mean, the weighted RMS of ``a − μ(s)`` on the same data and weights. Its evaluation
action (the MAP mean, deterministic) is ``diffql``'s: the same zero-latent chain.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.data.utils import DEVICE_TYPING
from torchrl.modules import DiffusionActor

from torchrl_dual import DDPMLastStepActor, WeightedMAPActorLoss
from torchrl_dual.objectives.diffql_actor_loss import DiffQLActorLoss
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.kits.build import projected_policy
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts.critics import make_critic
from torchrl_dual.recipe.parts.laplace_refits import LaplaceRefits
from torchrl_dual.recipe.settings.baselines import DiffQLActorSettings
from torchrl_dual.trainers.stepper import CriticActorStepper

ACTIVATIONS: dict[str, type[nn.Module]] = {"silu": nn.SiLU, "mish": nn.Mish}
"""``actor.activation`` -> its module (the names are
:data:`~torchrl_dual.recipe.settings.baselines.DIFFQL_ACTIVATIONS`)."""


# ----------------------------------------------------------------------------- networks
def vp_betas(num_steps: int, beta_min: float = 0.1, beta_max: float = 10.0) -> torch.Tensor:
    """Wang et al.'s variance-preserving schedule ``β_1 … β_N`` (their ``vp_beta_schedule``).

    Examples:
        >>> betas = vp_betas(5)
        >>> [round(b, 3) for b in betas.tolist()]
        [0.196, 0.459, 0.636, 0.755, 0.835]
        >>> round(float(torch.prod(1 - betas)), 4)  # ᾱ_N = exp(-(β_min + β_max) / 2)
        0.0064
    """
    t = torch.arange(1, num_steps + 1, dtype=torch.float64)
    log_alpha = -beta_min / num_steps - 0.5 * (beta_max - beta_min) * (2 * t - 1) / num_steps**2
    return (1.0 - log_alpha.exp()).float()


def make_diffusion_actor(
    settings: DiffQLActorSettings, obs_dim: int, action_dim: int, device: DEVICE_TYPING = "cpu"
) -> DiffusionActor:
    """TorchRL's ``DiffusionActor`` with an MLP score network ``ε̂(x_t, s, t)``, on ``device``.

    The network has ``depth`` hidden layers of ``activation`` and ends in ``nn.Linear``;
    the schedule is the VP one of :func:`vp_betas`.
    """
    a = settings
    layers: list[nn.Module] = []
    width = action_dim + obs_dim + 1
    for _ in range(a.depth):
        layers += [nn.Linear(width, a.hidden), ACTIVATIONS[a.activation]()]
        width = a.hidden
    layers.append(nn.Linear(width, action_dim))
    actor = DiffusionActor(action_dim, score_network=nn.Sequential(*layers), num_steps=a.num_steps)
    ddpm = actor.module
    betas = vp_betas(a.num_steps)
    with torch.no_grad():
        ddpm.betas.copy_(betas)
        ddpm.alphas.copy_(1.0 - betas)
        ddpm.alphas_cumprod.copy_(torch.cumprod(1.0 - betas, 0))
    return actor.to(device)


class ActionBox(nn.Module):
    """Clamps an action to the env's box ``[low, high]``."""

    def __init__(self, low: torch.Tensor, high: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("low", low.clone())
        self.register_buffer("high", high.clone())

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        """Clamps ``action`` ``[..., A]`` to ``[low, high]``."""
        return torch.maximum(torch.minimum(action, self.high), self.low)


# ----------------------------------------------------------------------------- learners
class DiffQLLearner(Learner):
    """Diff-QL: one ``budget.offline_updates`` stage offline, then the same update online."""

    title = "Diff-QL"
    shared_stages = ("actor_critic",)

    def __init__(self, run: RunContext) -> None:
        self.run = run
        settings = self.settings = run.settings
        spec = run.env.action_spec
        obs_dim, action_dim = run.data.obs_dim, run.data.action_dim
        s = settings.actor
        self.actor = make_diffusion_actor(s, obs_dim, action_dim, settings.device)
        self.critic = make_critic(settings, obs_dim, action_dim)
        self.box = ActionBox(spec.space.low, spec.space.high).to(settings.device)
        self.actor_objective = DiffQLActorLoss.from_iql(
            self.actor, self.critic.loss, self.box, eta=s.eta
        )
        self.actor_optimizer = adam(self.actor.parameters(), lr=s.lr)
        self.stepper = CriticActorStepper(
            self,
            self.critic.optimizer,
            self.actor_optimizer,
            target_update=self.critic.target_updater,
            actor_max_grad_norm=s.max_grad_norm,
        )
        self.clamp = TensorDictModule(self.box, in_keys=["action"], out_keys=["action"])
        self.evaluation_policy = TensorDictSequential(self.actor, self.clamp)
        self.exploration_policy = self.projected(self.evaluation_policy)

    def projected(self, policy: nn.Module) -> nn.Module:
        """``policy`` followed by the env kit's ``action_projection``, if it has one."""
        return projected_policy(self.settings, policy)

    def modules(self) -> dict:
        """The actor, the critic's modules and the actor's optimizer."""
        return {
            "actor": self.actor,
            **self.critic.modules(),
            "actor_optimizer": self.actor_optimizer,
        }

    def offline_stages(self) -> list:
        """One offline stage: ``budget.offline_updates`` actor-critic updates on D_offline."""
        return [("actor_critic", self.run.pretrain_updates)]

    def critic_loss(self, batch: TensorDictBase) -> tuple[dict, dict]:
        """The IQL critic's terms (TD to ``r + γ V(s')`` and the expectile V loss)."""
        return self.critic.loss.critic_terms(batch), {}

    def actor_loss(self, batch: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """``L_bc + η · loss_q`` and its two terms (logged as ``loss_bc``, ``loss_q``)."""
        out = self.actor_objective(batch)
        return out["loss_actor"], {
            "q_pi": out["q_pi"], "loss_bc": out["bc_term"], "loss_q": out["q_term"]
        }  # fmt: skip

    def update(self, batch: TensorDictBase) -> dict:
        """One IQL critic step, then one actor step on ``L_bc + η · loss_q`` (clipped)."""
        return dict(self.stepper.update(batch).items())


class DiffQLLALearner(LaplaceRefits, DiffQLLearner):
    """Diff-QL w LA: Diff-QL's training, acting with the Laplace ensemble of its last DDPM step.

    The ensemble of Eq. 8-9 with ``λ = 0`` noise, refitted every
    ``budget.laplace_refit_every`` updates (:class:`LaplaceRefits`) with ``σ̄`` =
    :meth:`noise_std`.
    """

    title = "Diff-QL w LA"
    shared_stages = ("actor_critic",)  # offline_cache: Diff-QL's offline updates only
    online_keys = (
        "laplace.num_samples",
        "laplace.prior_precision",
        "laplace.posterior_temperature",
        "laplace.temperature",
        "laplace.max_weight",
        "exploration.shift_weight",
    )

    def __init__(self, run: RunContext) -> None:
        super().__init__(run)
        la = run.settings.laplace
        self.last_step = DDPMLastStepActor(self.actor, latent="zero")
        # only its advantage weights are used (σ̄ and Eq. 8's Hessian); Diff-QL trains the actor
        self.laplace_weight_fn = WeightedMAPActorLoss.from_iql(
            self.last_step,
            self.critic.loss,
            weighting="advantage",
            temperature=la.temperature,
            max_weight=la.max_weight,
        ).advantage_weights
        self.act_with_ensemble(self.last_step)  # Eq. 9 + Eq. 10 with λ = 0
        self.evaluation_policy = self.ensemble  # the MAP mean under DETERMINISTIC
        # modules(): Diff-QL's and the ensemble's own state (the actor's weights once)

    @torch.no_grad()
    def noise_std(self) -> torch.Tensor:
        """``σ̄`` of the fit, ``[A]``: the weighted RMS of the data actions around the mean ``μ``.

        ``σ̄_a² = Σ_i w_i (a_i − μ(s_i))_a² / Σ_i w_i`` on ``D_offline ∪ D_online``:
        the maximiser of Eq. (7) in ``σ̄`` at the current mean ``μ`` (the
        zero-latent chain) with the same weights ``w_i`` as Eq. (8); Diff-QL's loss
        trains no ``σ̄``. :meth:`~LaplaceRefits.fit_laplace` sets it, then fits Eq.
        (8) (Alg. 1 lines 9 and 17 on the last DDPM step).
        """
        total, weight_sum = 0.0, 0.0
        for batch in self.run.all_transitions():
            weight = self.laplace_weight_fn(batch)
            residual = batch["action"] - self.last_step(batch["observation"])
            total = total + (weight[:, None] * residual.square()).sum(0)
            weight_sum = weight_sum + weight.sum()
        return (total / weight_sum).sqrt()
