"""A TorchRL collector for DUAL's acting policy before its offline stages have run.

TorchRL's :class:`~torchrl.collectors.Collector` calls the policy once while it is
constructed, to size its output buffers (``_maybe_make_final_rollout``). DUAL's ensemble
policy (Eq. 9) samples from the last-layer posterior of Eq. 8, which does not exist yet
when a trainer is assembled: :class:`~torchrl_dual.trainers.OfflineStagesHook` fits it at
the trainer's ``setup`` stage, after the collector is built. The probe therefore runs in
TorchRL's deterministic exploration mode, where the ensemble acts with its MAP mean and
writes the same keys; collection itself runs in the mode of the caller.

Example:
    >>> import torch
    >>> from tensordict.nn import TensorDictModule
    >>> from torchrl.envs import GymEnv
    >>> from torchrl_dual.trainers import dual_collector
    >>> env = GymEnv("Pendulum-v1")
    >>> policy = TensorDictModule(torch.nn.Linear(3, 1), ["observation"], ["action"])
    >>> collector = dual_collector(env, policy, frames_per_batch=4, total_frames=4)
    >>> next(iter(collector))["action"].shape
    torch.Size([4, 1])
    >>> collector.shutdown()
"""

from __future__ import annotations

from typing import Any

from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type

__all__ = ["dual_collector"]


def dual_collector(env: Any, policy: Any, **kwargs: Any) -> Collector:
    """A TorchRL collector whose construction-time probe of ``policy`` runs deterministically.

    The probe needs no posterior. ``kwargs`` go to
    :class:`~torchrl.collectors.Collector`.

    Args:
        env (EnvBase): the online env (with :class:`~torchrl_dual.transforms.PreviousTransition`
            for DUAL's shift signal).
        policy (TensorDictModuleBase): the acting policy, e.g. ``make_dual_policy(...)``.
        **kwargs: TorchRL's collector arguments (``frames_per_batch``, ``total_frames``,
            ...). ``auto_register_policy_transforms`` defaults to ``False``: DUAL's policy
            has no recurrent module, so the collector appends no ``InitTracker`` or
            ``TensorDictPrimer`` to the env (and TorchRL 0.14 warns of none).

    Returns:
        Collector: the collector.
    """
    kwargs.setdefault("auto_register_policy_transforms", False)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return Collector(env, policy, **kwargs)
