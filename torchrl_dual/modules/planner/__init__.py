"""The planner as a policy (Eq. 5) and as DUAL's transition model ``p(s'|s, a)``."""

from torchrl_dual.modules.planner.planner_policy import PlannerPolicy
from torchrl_dual.modules.planner.planner_sampler import PlannerSampler
from torchrl_dual.modules.planner.transition_model import TransitionModel

__all__ = ["PlannerPolicy", "PlannerSampler", "TransitionModel"]
