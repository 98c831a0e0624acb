"""torchrl-dual: DUAL (Diffusion Uncertainty-Aware offline-to-online RL) for TorchRL.

The public parts, each usable on its own in a TorchRL pipeline:

* :class:`DiffusionPlannerLoss` — the trajectory planner's denoising loss (Eq. 3);
* :class:`DistillationLoss` — progressive distillation to a one-step sampler;
* :class:`WeightedMAPActorLoss` — the weighted MAP actor loss (Eq. 7);
* :class:`LaplaceEnsembleActor` — last-layer Laplace ensemble policy (Eq. 8-9);
* :class:`ShiftAwareNoise` — shift-aware exploration variance (Eq. 10).
"""

from torchrl_dual.modules import (
    DDPMLastStepActor,
    LaplaceEnsembleActor,
    LastLayerLaplace,
    LinearHeadActor,
    PlannerActor,
    PlannerPolicy,
    ShiftAwareNoise,
    TransitionModel,
    make_dual_policy,
)
from torchrl_dual.objectives import (
    DiffusionPlannerLoss,
    DistillationLoss,
    WeightedMAPActorLoss,
    progressive_distillation,
    train_planner,
)

__version__ = "0.1.0"

__all__ = [
    "DDPMLastStepActor",
    "DiffusionPlannerLoss",
    "DistillationLoss",
    "LaplaceEnsembleActor",
    "LastLayerLaplace",
    "LinearHeadActor",
    "PlannerActor",
    "PlannerPolicy",
    "ShiftAwareNoise",
    "TransitionModel",
    "WeightedMAPActorLoss",
    "make_dual_policy",
    "progressive_distillation",
    "train_planner",
]
