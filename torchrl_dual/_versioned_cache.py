"""A value derived from modules' tensors, recomputed only when one of them changes.

PyTorch's fused optimizers (``torch.optim.Adam(fused=True)``, as the recipe builds its
Adams) change the parameters in place without moving their version counters (torch
2.13). A cache that trusts those counters would keep serving values of the weights before
the step, and did: DUAL's acting path between two Laplace refits, for an actor trained
with fused Adam. Importing this module registers one global optimizer step hook that
moves the counters of a fused group's parameters after its step
(:func:`mark_fused_steps`); ``tests/test_versioned_cache.py`` fails once PyTorch moves
them itself, so that the hook can go. A CUDA graph's replay moves no counter either and
runs no hook: code that replays an update as a graph moves the counters itself, as the
recipe's ``GraphedUpdate`` does.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, Generic, TypeVar

import torch
from torch import Tensor, nn
from torch.optim.optimizer import Optimizer, register_optimizer_step_post_hook

T = TypeVar("T")


def mark_fused_steps(optimizer: Optimizer, args: Any = (), kwargs: Any = None) -> None:
    """Moves the version counter of every parameter of ``optimizer``'s fused groups.

    As any other in-place update does. This is the step hook this module registers for
    every optimizer.

    Examples:
        >>> import torch
        >>> weight = torch.nn.Parameter(torch.zeros(2))
        >>> optimizer = torch.optim.Adam([weight], fused=True)
        >>> weight.grad = torch.ones(2)
        >>> before = weight._version
        >>> optimizer.step()  # the hook runs after every step
        >>> weight._version > before
        True
    """
    for group in optimizer.param_groups:
        if group.get("fused"):
            params = [p for p in group["params"] if p.grad is not None]
            if params:
                torch.autograd.graph.increment_version(params)


_FUSED_STEP_HOOK = register_optimizer_step_post_hook(mark_fused_steps)

_Slot = tuple[dict, str, Tensor, int, int]
"""``(table, name, tensor, storage address, version)`` of one source tensor, ``table`` the
``_parameters`` or ``_buffers`` dict of its module."""


class VersionedCache(Generic[T]):
    """Caches ``compute()`` until a parameter or buffer of ``modules`` is modified or replaced.

    The sources are the direct parameters and buffers of each module of ``modules`` (not
    their submodules': list those too). A source is

    * modified when its version counter moves (every in-place operation bumps it:
      optimizer steps, fused ones through the hook above, ``copy_`` in
      ``load_state_dict``, ...; not an edit through ``tensor.data``, which has a counter
      of its own);
    * replaced when its module's table holds another tensor under its name
      (``load_state_dict(..., assign=True)``, ``module.weight = nn.Parameter(...)``) or
      when its storage moves (``Module.double()`` and ``.to()`` keep a parameter's
      identity and version but give it new storage).

    Modules keep their identity through all of these, so the check reads each module's
    tables directly (no ``nn.Module.__getattr__``): it runs at every call, on the action
    path. A parameter or buffer *registered* after the value was computed is not seen
    until the next recompute. ``compute`` runs without autograd: use the cache on
    inference paths only. Under ``torch.compile`` the check (a host-side comparison) is
    not traced: ``compute`` runs inside the compiled graph, from the current tensors (so
    a captured CUDA graph replays it too).

    Examples:
        >>> import torch
        >>> layer = torch.nn.Linear(3, 1)
        >>> calls = []
        >>> cache = VersionedCache([layer], lambda: calls.append(1) or layer.weight * 2)
        >>> _ = cache.get(); _ = cache.get()
        >>> len(calls)
        1
        >>> with torch.no_grad():  # an in-place change (an optimizer step): recomputed
        ...     _ = layer.weight.add_(1.0)
        >>> _ = cache.get(); len(calls)
        2
    """

    def __init__(self, modules: Iterable[nn.Module], compute: Callable[[], T]) -> None:
        self.modules = tuple(modules)
        for module in self.modules:
            if not isinstance(module, nn.Module):
                raise TypeError(
                    f"VersionedCache watches modules' parameters and buffers, got a "
                    f"{type(module).__name__}; pass the module that holds the tensor."
                )
        self.compute = compute
        self._slots: list[_Slot] | None = None
        self._value: T | None = None

    def _capture(self) -> list[_Slot]:
        return [
            (table, name, tensor, tensor.data_ptr(), tensor._version)
            for module in self.modules
            for table in (module._parameters, module._buffers)
            for name, tensor in table.items()
            if tensor is not None
        ]

    def _valid(self) -> bool:
        slots = self._slots
        if slots is None:
            return False
        for table, name, tensor, address, version in slots:
            current = table.get(name)
            if current is not tensor or current._version != version:
                return False
            if current.data_ptr() != address:
                return False
        return True

    def get(self) -> T:
        """The cached value, recomputed first if a source changed."""
        if torch.compiler.is_compiling():
            with torch.no_grad():
                return self.compute()
        if not self._valid():
            with torch.no_grad():
                self._value = self.compute()
            self._slots = self._capture()
        return self._value
