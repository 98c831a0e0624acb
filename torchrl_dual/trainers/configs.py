"""DUAL's parts in TorchRL's Hydra ``ConfigStore`` (``torchrl.trainers.algorithms.configs``).

:func:`register_configs` stores dataclass configs with ``_target_`` next to TorchRL's own
groups, so a run composed from TorchRL's groups can pick DUAL's parts:

===================================  =================================================================
group=name                           target
===================================  =================================================================
``loss=dual``                        :class:`~torchrl_dual.objectives.DUALLoss` (Alg. 1 l. 7-8, Eq. 7)
``loss=dual_iql_critic``             :class:`~torchrl_dual.objectives.IQLCriticLoss` (its critic)
``loss=dual_diffusion_planner``      :class:`~torchrl_dual.objectives.DiffusionPlannerLoss` (Eq. 3)
``loss=dual_distillation``           :class:`~torchrl_dual.objectives.DistillationLoss` (Alg. 1 l. 5)
``exploration=shift_aware_noise``    :class:`~torchrl_dual.modules.ShiftAwareNoise` (Eq. 10)
``hook=laplace_refit``               :class:`~torchrl_dual.trainers.LaplaceRefitHook` (Eq. 8)
``hook=dual_signals``                :class:`~torchrl_dual.trainers.DUALSignalsLogHook` (Eq. 9-10)
``hook=normalized_score``            :class:`~torchrl_dual.trainers.NormalizedScoreLogHook`
``replay_buffer=offline_to_online``  TorchRL's ``OfflineToOnlineReplayBuffer`` (fixed offline share)
``trainer=dual``                     :class:`~torchrl_dual.trainers.DUALTrainer`
===================================  =================================================================

Fields holding modules (the actor, the planner, the collector, ...) default to ``None``:
modules are not config values, so build a partial from the config and complete it with
them, ``instantiate(cfg, _partial_=True)(actor=actor, ...)``
(``tests/trainers/test_configs.py`` trains a run built this way).

TorchRL's groups share names with the recipe's (``logger=csv``): once they are stored,
Hydra validates the recipe's ``logger/csv.yaml`` against TorchRL's schema and composing
the recipe's config fails. Compose the recipe's config before calling
:func:`register_configs`, or in another process; ``tests/trainers/conftest.py`` restores
the store after each test.

Example:
    >>> from hydra.core.config_store import ConfigStore
    >>> from torchrl_dual.trainers import register_configs
    >>> register_configs()
    >>> "dual.yaml" in ConfigStore.instance().repo["loss"]
    True
    >>> "dual.yaml" in ConfigStore.instance().repo["trainer"]
    True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = [
    "DUALLossConfig",
    "DUALTrainerConfig",
    "DiffusionPlannerLossConfig",
    "DistillationLossConfig",
    "DUALSignalsLogHookConfig",
    "IQLCriticLossConfig",
    "LaplaceRefitHookConfig",
    "NormalizedScoreLogHookConfig",
    "OfflineToOnlineReplayBufferConfig",
    "ShiftAwareNoiseConfig",
    "register_configs",
]


@dataclass
class IQLCriticLossConfig:
    """Config of :class:`~torchrl_dual.objectives.IQLCriticLoss`, DUAL's critic.

    IQL's twin Q and expectile V (IQL's paper values: ``loss_function="l2"``,
    ``expectile`` 0.7 or 0.9).

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl.modules import MLP, ValueOperator
        >>> make = instantiate(OmegaConf.structured(IQLCriticLossConfig(expectile=0.9)),
        ...                    _partial_=True)  # the networks complete the partial
        >>> critic = make(
        ...     qvalue_network=ValueOperator(MLP(in_features=5, out_features=1, num_cells=[8]),
        ...                                  in_keys=["observation", "action"]),
        ...     value_network=ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]),
        ...                                 in_keys=["observation"]))
        >>> type(critic).__name__, critic.expectile
        ('IQLCriticLoss', 0.9)
    """

    qvalue_network: Any = None
    value_network: Any = None
    num_qvalue_nets: int = 2
    loss_function: str = "l2"
    expectile: float = 0.7
    _target_: str = "torchrl_dual.objectives.IQLCriticLoss"
    _partial_: bool = False


@dataclass
class DUALLossConfig:
    """Config of :class:`~torchrl_dual.objectives.DUALLoss`: the critic and Eq. 7's actor on it.

    The weighted MAP actor of Eq. 7 on the critic (Alg. 1 lines 7-8). ``critic`` is the
    critic loss itself, e.g. built from ``loss=dual_iql_critic``: Eq. 7 then reads the
    weights that loss trains.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl_dual.modules import LinearHeadActor
        >>> from torchrl_dual.objectives import IQLCriticLoss
        >>> critic = IQLCriticLoss(
        ...     ValueOperator(MLP(in_features=5, out_features=1, num_cells=[8]),
        ...                   in_keys=["observation", "action"]),
        ...     ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]),
        ...                   in_keys=["observation"]))
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 2)
        >>> config = OmegaConf.structured(DUALLossConfig(temperature=2.0))
        >>> make = instantiate(config, _partial_=True)
        >>> loss = make(actor=actor, critic=critic)
        >>> type(loss).__name__, loss.actor_objective.temperature
        ('DUALLoss', 2.0)
    """

    actor: Any = None
    critic: Any = None
    weighting: str = "advantage"
    temperature: float = 3.0
    max_weight: float = 100.0
    entropy_coef: float = 0.2
    reduction: str | None = None
    _target_: str = "torchrl_dual.objectives.DUALLoss"
    _partial_: bool = False


@dataclass
class DiffusionPlannerLossConfig:
    """:class:`~torchrl_dual.objectives.DiffusionPlannerLoss`: Eq. 3 on H-step windows.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), hidden=16, depth=1)
        >>> config = DiffusionPlannerLossConfig(action_condition_prob=0.25)
        >>> loss = instantiate(OmegaConf.structured(config), _partial_=True)(model=model)
        >>> type(loss).__name__, loss.action_condition_prob
        ('DiffusionPlannerLoss', 0.25)
    """

    model: Any = None
    action_condition_prob: float = 0.5
    reduction: str = "mean"
    _target_: str = "torchrl_dual.objectives.DiffusionPlannerLoss"
    _partial_: bool = False


@dataclass
class DistillationLossConfig:
    """:class:`~torchrl_dual.objectives.DistillationLoss`: one progressive-distillation round.

    Examples:
        >>> import copy
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> layout = TrajectoryLayout(3, 2, 4)
        >>> teacher = TrajectoryDiffusion(layout, num_steps=4, hidden=16, depth=1)
        >>> student = copy.deepcopy(teacher)
        >>> student.num_steps = 2  # one round: 4 -> 2 steps
        >>> make = instantiate(OmegaConf.structured(DistillationLossConfig()), _partial_=True)
        >>> loss = make(student=student, teacher=teacher)
        >>> type(loss).__name__, loss.student.num_steps, loss.teacher.num_steps
        ('DistillationLoss', 2, 4)
    """

    student: Any = None
    teacher: Any = None
    action_condition_prob: float = 0.5
    reduction: str = "mean"
    _target_: str = "torchrl_dual.objectives.DistillationLoss"
    _partial_: bool = False


@dataclass
class ShiftAwareNoiseConfig:
    """:class:`~torchrl_dual.modules.ShiftAwareNoise`: Eq. 10's shift-aware variance.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl.data import Bounded
        >>> make = instantiate(OmegaConf.structured(ShiftAwareNoiseConfig(shift_weight=0.25)),
        ...                    _partial_=True)
        >>> noise = make(spec=Bounded(-1.0, 1.0, shape=(2,)))
        >>> type(noise).__name__, float(noise.shift_weight)
        ('ShiftAwareNoise', 0.25)
    """

    spec: Any = None
    shift_weight: float = 0.5
    shift_floor: float = 0.0
    extra_variance: float = 0.0
    _target_: str = "torchrl_dual.modules.ShiftAwareNoise"
    _partial_: bool = False


@dataclass
class LaplaceRefitHookConfig:
    """:class:`~torchrl_dual.trainers.LaplaceRefitHook`: Eq. 8 every ``interval`` steps.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from torchrl.modules import MLP
        >>> from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor
        >>> ensemble = LaplaceEnsembleActor(
        ...     LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 2))
        >>> make = instantiate(OmegaConf.structured(LaplaceRefitHookConfig(interval=100)),
        ...                    _partial_=True)
        >>> hook = make(ensemble=ensemble, batches_fn=lambda: [])
        >>> type(hook).__name__, hook.interval
        ('LaplaceRefitHook', 100)
    """

    ensemble: Any = None
    batches_fn: Any = None
    interval: int = 5000
    weight_fn: Any = None
    _target_: str = "torchrl_dual.trainers.LaplaceRefitHook"
    _partial_: bool = False


@dataclass
class DUALSignalsLogHookConfig:
    """:class:`~torchrl_dual.trainers.DUALSignalsLogHook`: Eq. 9-10's signals per batch.

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> hook = instantiate(OmegaConf.structured(DUALSignalsLogHookConfig(prefix="signals/")))
        >>> type(hook).__name__, hook.prefix
        ('DUALSignalsLogHook', 'signals/')
    """

    prefix: str = "dual/"
    log_pbar: bool = False
    _target_: str = "torchrl_dual.trainers.DUALSignalsLogHook"
    _partial_: bool = False


@dataclass
class NormalizedScoreLogHookConfig:
    """Config of :class:`~torchrl_dual.trainers.NormalizedScoreLogHook`.

    Logs the evaluation's score every ``interval`` collected batches (``evaluate`` is a
    callable: pass it in).

    Examples:
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> make = instantiate(OmegaConf.structured(NormalizedScoreLogHookConfig(interval=1)),
        ...                    _partial_=True)
        >>> hook = make(evaluate=lambda: {"normalized_score": 42.0})
        >>> hook(None)
        {'eval/normalized_score': 42.0}
    """

    evaluate: Any = None
    interval: int = 10
    prefix: str = "eval/"
    _target_: str = "torchrl_dual.trainers.NormalizedScoreLogHook"
    _partial_: bool = False


@dataclass
class OfflineToOnlineReplayBufferConfig:
    """Config of TorchRL's ``OfflineToOnlineReplayBuffer``, which TorchRL's store lacks.

    Each batch draws ``offline_fraction`` of it from ``D_offline`` (a Minari id, or a
    replay buffer passed in) and the rest from the online storage, a fixed share as DUAL
    samples.

    Examples:
        >>> import torch
        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> from tensordict import TensorDict
        >>> from torchrl.data import LazyTensorStorage, ReplayBuffer
        >>> offline = ReplayBuffer(storage=LazyTensorStorage(10))
        >>> _ = offline.extend(TensorDict(observation=torch.randn(10, 3), batch_size=[10]))
        >>> config = OfflineToOnlineReplayBufferConfig(online_capacity=100, batch_size=8)
        >>> make = instantiate(OmegaConf.structured(config), _partial_=True)
        >>> replay = make(offline_dataset=offline)
        >>> _ = replay.extend(TensorDict(observation=torch.randn(4, 3), batch_size=[4]))
        >>> replay.sample().shape  # half offline, half online
        torch.Size([8])
    """

    offline_dataset: Any = None
    online_capacity: int = 1_000_000
    offline_fraction: float = 0.5
    batch_size: int = 256
    _target_: str = "torchrl.data.OfflineToOnlineReplayBuffer"
    _partial_: bool = False


@dataclass
class DUALTrainerConfig:
    """:class:`~torchrl_dual.trainers.DUALTrainer`: Algorithm 1 on TorchRL's ``Trainer``.

    Examples:
        The trainer's modules complete the partial (:class:`~torchrl_dual.trainers.DUALTrainer`
        shows a run built from them):

        >>> from hydra.utils import instantiate
        >>> from omegaconf import OmegaConf
        >>> make = instantiate(OmegaConf.structured(DUALTrainerConfig(total_frames=40)),
        ...                    _partial_=True)
        >>> make.func.__name__, make.keywords["total_frames"], make.keywords["refit_interval"]
        ('DUALTrainer', 40, 5000)
    """

    collector: Any = None
    policy: Any = None
    stepper: Any = None
    replay_buffer: Any = None
    offline_stages: Any = None
    total_frames: int = 8000
    optim_steps_per_batch: int = 1000
    refit_interval: int = 5000
    weight_fn: Any = None
    batch_size: int | None = None
    progress_bar: bool = True
    save_trainer_file: Any = None
    save_trainer_interval: int = 10000
    log_interval: int = 10000
    logger: Any = None
    log_signals: bool = True
    evaluation: Any = None
    _target_: str = "torchrl_dual.trainers.DUALTrainer"
    _partial_: bool = False


_ENTRIES = (
    ("loss", "dual", DUALLossConfig),
    ("loss", "dual_iql_critic", IQLCriticLossConfig),
    ("loss", "dual_diffusion_planner", DiffusionPlannerLossConfig),
    ("loss", "dual_distillation", DistillationLossConfig),
    ("exploration", "shift_aware_noise", ShiftAwareNoiseConfig),
    ("hook", "laplace_refit", LaplaceRefitHookConfig),
    ("hook", "dual_signals", DUALSignalsLogHookConfig),
    ("hook", "normalized_score", NormalizedScoreLogHookConfig),
    ("replay_buffer", "offline_to_online", OfflineToOnlineReplayBufferConfig),
    ("trainer", "dual", DUALTrainerConfig),
)


def register_configs() -> None:
    """Registers TorchRL's config groups, then DUAL's entries in them (idempotent)."""
    from hydra.core.config_store import ConfigStore
    from torchrl.trainers.algorithms import configs as torchrl_configs

    store = ConfigStore.instance()
    # TorchRL stores its groups when the module is first imported, not again: a store
    # emptied since (tests/trainers/conftest.py) is refilled by its private registrar
    if "iql.yaml" not in store.repo.get("loss", {}):
        torchrl_configs._register_configs()
    for group, name, node in _ENTRIES:
        store.store(group=group, name=name, node=node)
