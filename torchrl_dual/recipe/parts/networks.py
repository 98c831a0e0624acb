"""DUAL's networks, loss and acting policy built from the config (Algorithm 1 line 1).

Each ``make_*`` builds one part; :class:`~torchrl_dual.recipe.DualLearner` calls them in a
fixed order (teacher, transition-model copy, actor, critics) so a seed gives the same
weights.
"""

from __future__ import annotations

import copy

from omegaconf import DictConfig
from tensordict.nn import TensorDictSequential
from torchrl.data.tensor_specs import TensorSpec

from torchrl_dual import PlannerActor, TransitionModel, WeightedMAPActorLoss, make_dual_policy
from torchrl_dual.data import OfflineDataset
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import LastLayerActor
from torchrl_dual.recipe.kits.build import env_kit
from torchrl_dual.recipe.parts.critics import Critic


def make_planner(cfg: DictConfig, data: OfflineDataset) -> TrajectoryDiffusion:
    """The N-step diffusion planner ``g_θ'`` (Eq. 3), its normalizer fitted on ``D_offline``."""
    p = cfg.planner
    layout = TrajectoryLayout(data.obs_dim, data.action_dim, p.horizon)
    model = TrajectoryDiffusion(
        layout, num_steps=p.num_steps, schedule=p.schedule, hidden=p.hidden, depth=p.depth
    )
    model.normalizer.fit(data.transitions["observation"], data.transitions["action"])
    return model.to(cfg.device)


def student_like(teacher: TrajectoryDiffusion, num_steps: int = 1) -> TrajectoryDiffusion:
    """An untrained copy of the teacher (architecture, initial weights and fitted
    normalizer) sampled with ``num_steps`` steps, for loading the distilled student into."""
    student = copy.deepcopy(teacher)
    student.num_steps = num_steps
    return student


def make_actor(cfg: DictConfig, teacher: TrajectoryDiffusion) -> PlannerActor:
    """The actor ``π_θ`` (Eq. 5, 7): a planner shaped like the teacher with
    ``distillation.final_steps`` steps (1 for DUAL), whose weights the distillation loads.

    Built before any training, it holds the teacher's fresh initialisation and its
    normalizer fitted on ``D_offline``: with ``actor.init=scratch`` that is what Eq. 7
    starts from (the distillation then only feeds the transition model)."""
    student = student_like(teacher, cfg.distillation.final_steps)
    return PlannerActor(student, latent=cfg.actor.latent, init_std=cfg.actor.init_std)


def make_transition_model(
    cfg: DictConfig, teacher: TrajectoryDiffusion, actor: PlannerActor
) -> TransitionModel:
    """``p(s' | s, a; θ)``, the source of Eq. (10)'s ``ŝ_t`` (``exploration.transition_model``).

    ``frozen``: its own frozen copy of the distilled student (loaded after distillation),
    which the actor's fine-tuning leaves alone; saved inside the ensemble. ``shared``: the
    actor's own fine-tuned planner (Alg. 1's single ``θ``), held by reference and saved
    only as the actor's weights.
    """
    if cfg.exploration.transition_model == "frozen":
        return TransitionModel(student_like(teacher, cfg.distillation.final_steps))
    return TransitionModel(actor.model, frozen=False)


def make_actor_loss(
    cfg: DictConfig, actor: PlannerActor, critic: Critic, action_spec: TensorSpec
) -> WeightedMAPActorLoss:
    """The weighted MAP actor loss of Eq. (7) on the critics; ``action_spec`` bounds the
    actions at which the ``sac`` weighting reads Q, whose ``α`` is the critic's
    ``entropy_coef`` when it has one (SO2: the same ``α`` as its targets)."""
    a = cfg.actor
    entropy = {"entropy_coef": cfg.critic.entropy_coef} if "entropy_coef" in cfg.critic else {}
    return WeightedMAPActorLoss.from_iql(
        actor,
        critic.loss,
        weighting=a.weighting,
        temperature=a.temperature,
        max_weight=a.max_weight,
        action_spec=action_spec,
        **entropy,
    )


def make_policy(
    cfg: DictConfig,
    actor: LastLayerActor,
    action_spec: TensorSpec,
    transition: TransitionModel | None = None,
) -> TensorDictSequential:
    """The acting policy of ``cfg``'s ``laplace`` and ``exploration`` sections: the
    ensemble of Eq. (9) over the Laplace posterior (or, with ``laplace.uq=latent``, over
    planner latents), which also answers the transition model's ``ŝ_t`` when there is one,
    then the shift-aware noise (Eq. 10). DUAL's, and the ``*_la`` baselines' (no
    transition model, ``λ = 0``)."""
    return make_dual_policy(
        actor,
        action_spec,
        transition_model=transition,
        num_samples=cfg.laplace.num_samples,
        prior_precision=cfg.laplace.prior_precision,
        posterior_temperature=cfg.laplace.posterior_temperature,
        shift_weight=cfg.exploration.shift_weight,
        uncertainty=cfg.laplace.get("uq", "laplace"),
        action_projection=env_kit(cfg).action_projection,
        device=cfg.device,
    )
