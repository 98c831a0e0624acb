"""TorchRL loss modules of DUAL and of its critics, and the drivers that train with them."""

from torchrl_dual.objectives.calql import PENALTY_LAYOUTS, CalQLLoss
from torchrl_dual.objectives.density_ratio import DensityRatioLoss, make_density_ratio_network
from torchrl_dual.objectives.diffusion_planner import DiffusionPlannerLoss, train_planner
from torchrl_dual.objectives.distillation import DistillationLoss, progressive_distillation
from torchrl_dual.objectives.dual import DUALLoss
from torchrl_dual.objectives.iql_critic import IQLCriticLoss
from torchrl_dual.objectives.one_pass_iql import OnePassIQLLoss
from torchrl_dual.objectives.so2 import SO2QLoss
from torchrl_dual.objectives.soft_update import ForeachSoftUpdate
from torchrl_dual.objectives.update_loop import (
    ExponentialMovingAverage,
    UpdateCheckpoints,
    run_updates,
)
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS, WeightedMAPActorLoss

__all__ = [
    "PENALTY_LAYOUTS",
    "WEIGHTINGS",
    "CalQLLoss",
    "DUALLoss",
    "DensityRatioLoss",
    "DiffusionPlannerLoss",
    "DistillationLoss",
    "ExponentialMovingAverage",
    "ForeachSoftUpdate",
    "IQLCriticLoss",
    "OnePassIQLLoss",
    "SO2QLoss",
    "UpdateCheckpoints",
    "WeightedMAPActorLoss",
    "make_density_ratio_network",
    "progressive_distillation",
    "run_updates",
    "train_planner",
]
