"""torchrl-dual: DUAL (Diffusion Uncertainty-Aware offline-to-online RL) for TorchRL.

The public parts, each usable on its own in a TorchRL pipeline:

* :class:`DiffusionPlannerLoss` — the trajectory planner's denoising loss (Eq. 3);
* :class:`DistillationLoss` — progressive distillation to a one-step sampler;
* :class:`WeightedMAPActorLoss` — the weighted MAP actor loss (Eq. 7);
* :class:`LaplaceEnsembleActor` — last-layer Laplace ensemble policy (Eq. 8-9);
* :class:`ShiftAwareNoise` — shift-aware exploration variance (Eq. 10).
"""

from typing import TYPE_CHECKING

from torchrl_dual._lazy import lazy_exports

if TYPE_CHECKING:  # the eager imports, for type checkers and IDEs
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

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "DDPMLastStepActor": "torchrl_dual.modules",
        "LaplaceEnsembleActor": "torchrl_dual.modules",
        "LastLayerLaplace": "torchrl_dual.modules",
        "LinearHeadActor": "torchrl_dual.modules",
        "PlannerActor": "torchrl_dual.modules",
        "PlannerPolicy": "torchrl_dual.modules",
        "ShiftAwareNoise": "torchrl_dual.modules",
        "TransitionModel": "torchrl_dual.modules",
        "make_dual_policy": "torchrl_dual.modules",
        "DiffusionPlannerLoss": "torchrl_dual.objectives",
        "DistillationLoss": "torchrl_dual.objectives",
        "WeightedMAPActorLoss": "torchrl_dual.objectives",
        "progressive_distillation": "torchrl_dual.objectives",
        "train_planner": "torchrl_dual.objectives",
    },
)
