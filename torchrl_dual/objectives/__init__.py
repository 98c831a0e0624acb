"""TorchRL loss modules of DUAL."""

from torchrl_dual.objectives.diffusion_planner import DiffusionPlannerLoss
from torchrl_dual.objectives.distillation import DistillationLoss

__all__ = ["DiffusionPlannerLoss", "DistillationLoss"]
