"""TorchRL loss modules of DUAL and the drivers that train with them."""

from torchrl_dual.objectives.calql import PENALTY_LAYOUTS, CalQLLoss
from torchrl_dual.objectives.diffusion_planner import DiffusionPlannerLoss, train_planner
from torchrl_dual.objectives.distillation import DistillationLoss, progressive_distillation
from torchrl_dual.objectives.update_loop import ExponentialMovingAverage, run_updates
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS, WeightedMAPActorLoss

__all__ = [
    "PENALTY_LAYOUTS",
    "WEIGHTINGS",
    "CalQLLoss",
    "DiffusionPlannerLoss",
    "DistillationLoss",
    "ExponentialMovingAverage",
    "WeightedMAPActorLoss",
    "progressive_distillation",
    "run_updates",
    "train_planner",
]
