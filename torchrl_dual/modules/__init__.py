"""TorchRL modules of DUAL, one subpackage per concept.

* :mod:`~torchrl_dual.modules.actors` — last-layer actors (``PlannerActor``, ...);
* :mod:`~torchrl_dual.modules.planner` — the planner as a policy and as transition model;
* :mod:`~torchrl_dual.modules.laplace` — the Laplace posterior and the ensemble policy;
* :mod:`~torchrl_dual.modules.exploration` — the shift-aware noise;
* :func:`make_dual_policy` — DUAL's acting policy assembled from the above;
* :func:`exploration_signals` — what that policy wrote into a collected batch, as numbers.
"""

from torchrl_dual.modules.actors import (
    DDPMLastStepActor,
    LastLayerActor,
    LinearHeadActor,
    PlannerActor,
)
from torchrl_dual.modules.dual_policy import make_dual_policy
from torchrl_dual.modules.exploration import ShiftAwareNoise
from torchrl_dual.modules.exploration_signals import exploration_signals
from torchrl_dual.modules.laplace import LaplaceEnsembleActor, LastLayerLaplace
from torchrl_dual.modules.planner import (
    PlannerPolicy,
    PlannerSampler,
    RewardModel,
    TransitionModel,
)

__all__ = [
    "DDPMLastStepActor",
    "LaplaceEnsembleActor",
    "LastLayerActor",
    "LastLayerLaplace",
    "LinearHeadActor",
    "PlannerActor",
    "PlannerPolicy",
    "PlannerSampler",
    "RewardModel",
    "ShiftAwareNoise",
    "TransitionModel",
    "exploration_signals",
    "make_dual_policy",
]
