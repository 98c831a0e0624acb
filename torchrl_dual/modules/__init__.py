"""TorchRL modules of DUAL: planner policy, Laplace head, ensemble actor, exploration."""

from torchrl_dual.modules.ddpm_actor import DDPMLastStepActor
from torchrl_dual.modules.ensemble_actor import LaplaceEnsembleActor
from torchrl_dual.modules.laplace import LastLayerLaplace
from torchrl_dual.modules.last_layer import LastLayerActor, LinearHeadActor
from torchrl_dual.modules.planner_actor import PlannerActor
from torchrl_dual.modules.planner_policy import PlannerPolicy, PlannerSampler, TransitionModel
from torchrl_dual.modules.shift_aware import ShiftAwareNoise

__all__ = [
    "DDPMLastStepActor",
    "LaplaceEnsembleActor",
    "LastLayerActor",
    "LastLayerLaplace",
    "LinearHeadActor",
    "PlannerActor",
    "PlannerPolicy",
    "PlannerSampler",
    "ShiftAwareNoise",
    "TransitionModel",
]
