"""TorchRL loss modules of DUAL."""

from torchrl_dual.objectives.diffusion_planner import DiffusionPlannerLoss
from torchrl_dual.objectives.distillation import DistillationLoss
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS, WeightedMAPActorLoss

__all__ = ["WEIGHTINGS", "DiffusionPlannerLoss", "DistillationLoss", "WeightedMAPActorLoss"]
