"""How a run calls its learner's update: counted, eager, compiled or as CUDA graphs.

:class:`LearnerUpdates` is ``run.update``: the learner's update, counted, which the
offline stages call and TorchRL's ``Trainer`` steps as its optimization stepper. How the
update itself runs follows the ``compile.*`` keys, as TorchRL's sota-implementations name them.

* ``compile.compile=true``: ``learner.update`` through ``torch.compile``
  (``compile.compile_mode``). The losses trace whole (no graph break,
  ``tests/test_compile.py``); the backward passes and optimizer steps are their own
  graphs; Dynamo replays the update's Python side effects.
* ``compile.cudagraphs=true`` (``device=cuda`` only): the update, compiled or not, captured
  by tensordict's :class:`~tensordict.nn.CudaGraphModule` and replayed with each new batch
  copied into the captured one: one graph per phase (offline, online) and batch shape,
  since the critic's settings and SO2's stacked ``[k, B]`` batches differ between them.
  The optimizers are made ``capturable`` (their step counters on the device) before the
  first capture, after any checkpoint was loaded. A replay runs the captured kernels
  only, so an algorithm allows it when its update reads nothing but its batch and the
  networks' and optimizers' tensors and leaves every Python attribute as it was (its
  bookkeeping runs in :meth:`~torchrl_dual.recipe.Learner.after_update`);
  ``tests/recipe/test_graph_safe_updates.py`` checks this for every algorithm whose table
  entry does not say why it cannot (``Algorithm.no_cuda_graph``). A replay changes the
  parameters without moving their version counters, so after each one the counters of
  every parameter the optimizers hold are moved by hand: the acting path's caches
  (:class:`~torchrl_dual._versioned_cache.VersionedCache`) then see the update.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.trainers import OptimizationStepper, Trainer

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.learner import Learner
    from torchrl_dual.recipe.settings.schema import CompileSettings
    from torchrl_dual.recipe.settings.structured import RecipeSettings

CUDA_GRAPH_WARMUP = 3
"""Eager calls on a side stream before the capture (optimizer state, lazy buffers)."""


def make_update_step(
    learner: Learner, settings: CompileSettings | None, phase: Callable[[], Any]
) -> Callable[[TensorDictBase], dict]:
    """``batch -> metrics``: ``learner.update`` as ``settings`` (the ``compile`` section) asks.

    ``phase()`` names the current phase (one CUDA graph each).
    """
    update = learner.update
    if settings is not None and settings.compile:
        mode = settings.compile_mode
        update = torch.compile(update, mode=None if mode in (None, "default") else mode)
    if settings is None or not settings.cudagraphs:
        return update
    return GraphedUpdate(
        update,
        phase,
        lambda: make_capturable(optimizers_of(learner)),
        lambda: [p for o in optimizers_of(learner) for g in o.param_groups for p in g["params"]],
    )


class UpdatedRun(Protocol):
    """What :class:`LearnerUpdates` uses of its run (an :class:`~torchrl_dual.recipe.O2ORun`)."""

    settings: RecipeSettings
    learner: Learner
    replay: Any
    frames: int
    updates: int


class LearnerUpdates(OptimizationStepper):
    """The learner's update, counted: ``run.update(batch)``, and the trainer's stepper.

    Calling it runs one update of ``run.learner`` (eager, compiled or as a CUDA graph:
    ``compile.*``, :func:`~torchrl_dual.recipe.o2o.update_step.make_update_step`), the
    learner's ``after_update`` and counts it; the offline stages call it so. As TorchRL's
    ``OptimizationStepper`` of the online phase (Alg. 1 l. 14-16) it adds the replay's own
    step (e.g. balanced replay's priorities) and keeps the losses in :attr:`last`: the run
    logs the batch's last update's losses, so the step returns none for the trainer to
    average.
    """

    def __init__(self, run: UpdatedRun) -> None:
        self.run = run
        self.update = make_update_step(run.learner, run.settings.compile, lambda: run.frames > 0)
        self.last: dict = {}
        self._none = TensorDict()

    def __call__(self, batch: TensorDictBase) -> dict:
        """One learner update on ``batch``, counted; returns its metrics."""
        metrics = self.update(batch)
        self.run.learner.after_update()
        self.run.updates += 1
        return metrics

    def step(self, trainer: Trainer, sub_batch: TensorDictBase) -> TensorDictBase:
        """One counted update on ``sub_batch``, then the replay's own step."""
        self.last = {**self(sub_batch), **self.run.replay.after_update(sub_batch)}
        return self._none


class GraphedUpdate:
    """``update`` replayed as one CUDA graph per ``(phase(), batch shape)``.

    Args:
        update (callable): ``batch -> {name: 0-dim tensor}``, graph-safe (see the module).
        phase (callable): ``() -> hashable``, the phase the next call belongs to.
        prepare (callable): ``() -> None``, run once before the first graph is made.
        updated (callable): ``() -> [tensors]``, what the update changes in place (the
            optimizers' parameters), read once at the first graph: their version counters
            are moved after every call, as an eager update would.
    """

    def __init__(
        self,
        update: Callable[[TensorDictBase], dict],
        phase: Callable[[], Any],
        prepare: Callable[[], None] = lambda: None,
        updated: Callable[[], list[torch.Tensor]] = list,
    ) -> None:
        self.update, self.phase, self.prepare, self.updated = update, phase, prepare, updated
        self.graphs: dict[tuple, Callable] = {}
        self._updated: list[torch.Tensor] = []

    def _as_tensordict(self, batch: TensorDictBase) -> TensorDict:
        return TensorDict(self.update(batch))  # CudaGraphModule returns tensordicts

    def __call__(self, batch: TensorDictBase) -> dict:
        """Runs ``update`` on ``batch`` by replaying the CUDA graph of its phase and shape.

        The graph is captured at the first call of each ``(phase(), batch shape)``.
        """
        from tensordict.nn import CudaGraphModule

        key = (self.phase(), tuple(batch.shape))
        if key not in self.graphs:
            if not self.graphs:
                self.prepare()
                self._updated = list(self.updated())
            self.graphs[key] = CudaGraphModule(
                self._as_tensordict, in_keys=[], out_keys=[], warmup=CUDA_GRAPH_WARMUP
            )
        out = dict(self.graphs[key](batch).items())
        if self._updated:  # a replay moves no version counter
            torch.autograd.graph.increment_version(self._updated)
        return out


def optimizers_of(learner: Learner) -> list[torch.optim.Optimizer]:
    """Every optimizer the learner holds, directly or in its parts (critics, replays)."""
    found: dict[int, torch.optim.Optimizer] = {}
    seen: set[int] = set()
    todo: list[Any] = [learner]
    while todo:
        obj = todo.pop()
        if id(obj) in seen or isinstance(obj, torch.Tensor | torch.nn.Module):
            continue
        seen.add(id(obj))
        if isinstance(obj, torch.optim.Optimizer):
            found[id(obj)] = obj
        elif isinstance(obj, list | tuple | set):
            todo.extend(obj)
        elif isinstance(obj, dict):
            todo.extend(obj.values())
        elif hasattr(obj, "__dict__") and not isinstance(obj, type):
            todo.extend(vars(obj).values())
    return list(found.values())


def make_capturable(optimizers: list[torch.optim.Optimizer]) -> None:
    """Makes the optimizers capturable by a CUDA graph.

    Sets ``capturable=True`` in every parameter group and moves the step counters of the
    optimizers' state (if they have stepped or loaded a checkpoint) next to their
    parameters as float32, where a CUDA graph updates them (what ``torch.optim`` does
    when it loads the state of a capturable optimizer).

    Examples:
        >>> import torch
        >>> w = torch.nn.Parameter(torch.ones(2))
        >>> adam = torch.optim.Adam([w])
        >>> w.sum().backward(); adam.step()
        >>> make_capturable([adam])
        >>> adam.param_groups[0]["capturable"], adam.state[w]["step"].device.type
        (True, 'cpu')
    """
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            if "capturable" not in group:
                continue
            group["capturable"] = True
            for param in group["params"]:
                state = optimizer.state.get(param, {})
                if isinstance(state.get("step"), torch.Tensor):
                    state["step"] = state["step"].to(param.device, torch.float32)
