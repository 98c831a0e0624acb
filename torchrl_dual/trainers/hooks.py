"""DUAL's trainer hooks: the offline stages and the periodic Laplace refit.

Both are :class:`~torchrl.trainers.TrainerHookBase` subclasses, so any TorchRL
:class:`~torchrl.trainers.Trainer` accepts them (``hook.register(trainer)``), registers
them as trainer modules, and saves their progress in its checkpoint.

* :class:`OfflineStagesHook` runs Algorithm 1's offline phase (lines 1-9: the planner of
  Eq. 3, progressive distillation, actor-critic pre-training with Eq. 7's actor, the
  last-layer Laplace fit of Eq. 8) at the trainer's ``setup`` stage, once: the names of
  the finished stages are its ``state_dict``, so a trainer resumed from its checkpoint
  skips them.
* :class:`LaplaceRefitHook` refits the last-layer Laplace (Eq. 8) on
  ``D_offline ∪ D_online`` every ``interval`` optimizer steps (Algorithm 1, line 17), at
  the ``post_steps`` stage *before* the weight update that pushes the policy to the
  collector, so the collector acts with the refitted ensemble of Eq. 9.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase
from torchrl.trainers import Trainer, TrainerHookBase

__all__ = [
    "LaplaceRefitHook",
    "OfflineStagesHook",
    "RefitSchedule",
    "register_before_weight_update",
]


def register_before_weight_update(trainer: Trainer, op: Callable[[], None]) -> None:
    """Registers ``op`` at ``post_steps``, ahead of every op already there.

    TorchRL runs ``post_steps`` ops in registration order and has no priority argument;
    ``UpdateWeights`` (the push of the policy to the collector) is a ``post_steps`` op
    too, often registered first. This is the one place that reorders the trainer's
    private list; ``tests/trainers/test_hooks.py`` fails if TorchRL changes it.

    Args:
        trainer (Trainer): the TorchRL trainer.
        op (callable): ``() -> None``, e.g. a :class:`LaplaceRefitHook`.
    """
    trainer.register_op("post_steps", op)
    ops = trainer._post_steps_ops
    ops.insert(0, ops.pop())


class RefitSchedule:
    """Alg. 1 line 17's schedule, the one home of it (the recipe's learners, :class:`LaplaceRefitHook`).

    The posterior is refitted after the first block of updates that brings the count
    since the last fit to ``every``. Its owner checkpoints ``since``.

    Examples:
        >>> schedule = RefitSchedule(every=3)
        >>> schedule.count(2); schedule.due
        False
        >>> schedule.count(); schedule.due
        True
        >>> schedule.reset(); schedule.since
        0
    """

    def __init__(self, every: int) -> None:
        self.every, self.since = int(every), 0

    def count(self, updates: int = 1) -> None:
        """``updates`` more gradient updates since the last fit."""
        self.since += updates

    @property
    def due(self) -> bool:
        """Whether a refit is due (checked after each block of updates)."""
        return self.since >= self.every

    def reset(self) -> None:
        """A fit happened."""
        self.since = 0


class OfflineStagesHook(TrainerHookBase):
    """Runs named offline stages once, in order, before training (Alg. 1, lines 1-9).

    Args:
        stages: ``(name, callable)`` pairs, run in order; each callable takes no
            argument. A stage that was interrupted is run again from its start.

    Example:
        >>> from torchrl_dual.trainers import OfflineStagesHook
        >>> log = []
        >>> hook = OfflineStagesHook([("planner", lambda: log.append("p")),
        ...                           ("laplace", lambda: log.append("l"))])
        >>> hook()
        >>> hook.load_state_dict(hook.state_dict())
        >>> hook()  # finished stages are not run again
        >>> log
        ['p', 'l']
    """

    def __init__(self, stages: Sequence[tuple[str, Callable[[], Any]]]) -> None:
        names = [name for name, _ in stages]
        if len(set(names)) != len(names):
            raise ValueError(f"stage names must be unique, got {names}")
        self.stages = list(stages)
        self.done: list[str] = []

    def __call__(self) -> None:
        """Runs the stages not done yet, in order, marking each done once it returns."""
        for name, stage in self.stages:
            if name in self.done:
                continue
            stage()
            self.done.append(name)

    def state_dict(self) -> dict[str, Any]:
        """The names of the finished stages, ``{"done": [name, ...]}``."""
        return {"done": list(self.done)}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restores the finished stages from :meth:`state_dict`.

        Args:
            state_dict (dict): ``{"done": [name, ...]}``.

        Raises:
            ValueError: a name that is not one of this hook's stages.
        """
        known = {name for name, _ in self.stages}
        unknown = [name for name in state_dict["done"] if name not in known]
        if unknown:
            raise ValueError(f"checkpoint lists unknown offline stages {unknown}")
        self.done = list(state_dict["done"])

    def register(self, trainer: Trainer, name: str = "offline_stages") -> None:
        """Registers the hook as a trainer module (checkpointed) and at the trainer's ``setup``.

        Args:
            trainer (Trainer): the TorchRL trainer.
            name (str): the module's name in the trainer's state dict.
        """
        trainer.register_module(name, self)
        trainer.register_op("setup", self)


class LaplaceRefitHook(TrainerHookBase):
    """Refits the last-layer Laplace (Eq. 8) every ``interval`` optimizer steps (Alg. 1 l. 17).

    After the first batch of optimizer steps that brings the count since the last fit to
    ``interval`` (:class:`RefitSchedule`, the recipe's rule too).

    Args:
        ensemble: the :class:`~torchrl_dual.modules.LaplaceEnsembleActor` (Eq. 9) whose
            posterior is refitted.
        batches_fn: returns the batches to fit on, e.g. the offline and online storages
            of the replay buffer (``lambda: [offline[:], online[:]]``).
        interval: optimizer steps between refits (the trainer's optimizer-step count).
        weight_fn: the Eq. 7 weights ``w_i`` of each sample, e.g.
            ``WeightedMAPActorLoss.advantage_weights``; uniform when ``None``.

    The schedule's count, the step of the last refit and the number of refits are the
    hook's ``state_dict``.

    Example:
        >>> from torchrl_dual.trainers import LaplaceRefitHook
        >>> class Counting:  # stands in for a LaplaceEnsembleActor
        ...     fits = 0
        ...     def fit_laplace(self, batches, weight_fn=None):
        ...         self.fits += 1
        >>> class FakeTrainer:
        ...     _optim_count = 0
        >>> ensemble, trainer = Counting(), FakeTrainer()
        >>> hook = LaplaceRefitHook(ensemble, lambda: [], interval=100)
        >>> hook._trainer = trainer
        >>> for count in (70, 140, 210, 280, 350):  # 70 optimizer steps per collected batch
        ...     trainer._optim_count = count
        ...     hook()
        >>> ensemble.fits, hook.last_refit_step  # at 140 and 280 (not at each 100 crossed)
        (2, 280)
    """

    def __init__(
        self,
        ensemble: Any,
        batches_fn: Callable[[], Iterable[TensorDictBase]],
        interval: int,
        weight_fn: Callable[[TensorDictBase], torch.Tensor] | None = None,
    ) -> None:
        if interval < 1:
            raise ValueError(f"interval must be >= 1, got {interval}")
        self.ensemble = ensemble
        self.batches_fn = batches_fn
        self.interval = interval
        self.weight_fn = weight_fn
        self.schedule = RefitSchedule(interval)
        self.last_refit_step = 0
        self.num_refits = 0
        self._trainer: Any = None

    def __call__(self) -> None:
        """Refits the posterior once ``interval`` optimizer steps have passed since the last fit.

        The steps are the trainer's optimizer-step count; the fit runs under
        :func:`torch.no_grad` on ``batches_fn()``, weighted by ``weight_fn``.
        """
        step = self._trainer._optim_count
        self.schedule.count(step - self.last_refit_step - self.schedule.since)  # the new steps
        if self.schedule.due:
            with torch.no_grad():
                self.ensemble.fit_laplace(self.batches_fn(), weight_fn=self.weight_fn)
            self.schedule.reset()
            self.last_refit_step = step
            self.num_refits += 1

    def state_dict(self) -> dict[str, Any]:
        """The steps since the last refit, the step of the last refit, the refits."""
        return {
            "since": self.schedule.since,
            "last_refit_step": self.last_refit_step,
            "num_refits": self.num_refits,
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        """Restores the schedule and the counts from :meth:`state_dict`.

        Args:
            state_dict (dict): ``{"since", "last_refit_step", "num_refits"}``, each an int.
        """
        self.schedule.since = int(state_dict["since"])
        self.last_refit_step = int(state_dict["last_refit_step"])
        self.num_refits = int(state_dict["num_refits"])

    def register(self, trainer: Trainer, name: str = "laplace_refit") -> None:
        """Registers the hook as a trainer module and ahead of the policy's weight update.

        It runs at ``post_steps`` before ``UpdateWeights`` (:func:`register_before_weight_update`),
        so the collector receives the refitted posterior.

        Args:
            trainer (Trainer): the TorchRL trainer.
            name (str): the module's name in the trainer's state dict.
        """
        self._trainer = trainer
        trainer.register_module(name, self)
        register_before_weight_update(trainer, self)
