"""DUAL inside TorchRL's own trainer stack (:class:`torchrl.trainers.Trainer`).

Hooks any TorchRL trainer accepts (:class:`OfflineStagesHook`, :class:`LaplaceRefitHook`,
the logging hooks :class:`DUALSignalsLogHook` and :class:`NormalizedScoreLogHook`)
and the critic-then-actor optimization step DUAL's two optimizers need
(:class:`CriticActorStepper`, for any :class:`CriticActorLoss`), and :class:`DUALTrainer`, which wires them into one
TorchRL trainer. TorchRL marks its trainer APIs experimental; the one
work-arounds they need are :func:`register_before_weight_update` and
:func:`dual_collector`.
"""

from torchrl_dual.trainers.collector import dual_collector
from torchrl_dual.trainers.configs import register_configs
from torchrl_dual.trainers.dual_trainer import DUALTrainer
from torchrl_dual.trainers.hooks import (
    LaplaceRefitHook,
    OfflineStagesHook,
    RefitSchedule,
    register_before_weight_update,
)
from torchrl_dual.trainers.logging_hooks import DUALSignalsLogHook, NormalizedScoreLogHook
from torchrl_dual.trainers.stepper import CriticActorLoss, CriticActorStepper

__all__ = [
    "CriticActorLoss",
    "CriticActorStepper",
    "DUALSignalsLogHook",
    "DUALTrainer",
    "dual_collector",
    "LaplaceRefitHook",
    "NormalizedScoreLogHook",
    "OfflineStagesHook",
    "RefitSchedule",
    "register_configs",
    "register_before_weight_update",
]
