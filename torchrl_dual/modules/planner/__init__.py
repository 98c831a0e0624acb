"""The planner as a policy, as DUAL's transition model and as a reward model.

The planner as a policy (Eq. 5), as DUAL's transition model ``p(s'|s, a)``, and the reward
model of its generated transitions (EDIS's augmentation).
"""

from torchrl_dual.modules.planner.planner_policy import PlannerPolicy
from torchrl_dual.modules.planner.planner_sampler import PlannerSampler
from torchrl_dual.modules.planner.reward_model import RewardModel
from torchrl_dual.modules.planner.transition_model import TransitionModel

__all__ = ["PlannerPolicy", "PlannerSampler", "RewardModel", "TransitionModel"]
