"""Last-layer actors and the action box their draws are executed in.

Gaussian actors whose mean is affine in a final ``nn.Linear`` (the split Eq. 7-9 work on),
and the action box (:class:`ActionBox`, :class:`ClippedNormal`).
"""

from torchrl_dual.modules.actors.action_box import ActionBox, ClippedNormal
from torchrl_dual.modules.actors.ddpm_last_step_actor import DDPMLastStepActor
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.modules.actors.linear_head_actor import LinearHeadActor
from torchrl_dual.modules.actors.planner_actor import PlannerActor

__all__ = [
    "ActionBox",
    "ClippedNormal",
    "DDPMLastStepActor",
    "LastLayerActor",
    "LinearHeadActor",
    "PlannerActor",
]
