"""Private: the exact inference fast path of the one-step planner.

The fold, paired trunks and versioned cache used by
:class:`~torchrl_dual.modules.PlannerActor` on the action path.
"""

from torchrl_dual.diffusion._fast_path.one_step_fast_path import OneStepFastPath

__all__ = ["OneStepFastPath"]
