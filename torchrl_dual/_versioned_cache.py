"""A value derived from tensors, recomputed only when one of them changes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

import torch
from torch import Tensor

T = TypeVar("T")


class VersionedCache(Generic[T]):
    """Caches ``compute()`` until one of the tensors of ``sources()`` is modified or replaced.

    A tensor is modified when its version counter moves (every in-place operation bumps
    it: optimizer steps, ``copy_`` in ``load_state_dict``, ...). Replacement (``.to()``
    to another device or dtype, ``load_state_dict(..., assign=True)``) is detected by
    identity and storage on the tensors ``probe()`` returns (a parameter converted by
    ``Module.double()`` or ``.to()`` keeps its identity but gets new storage), all of
    ``sources()`` by default; pass a
    few representative tensors (e.g. the first and last weights of a network) when
    ``sources()`` is long, since the check runs at every call. ``compute`` runs without
    autograd: use the cache on inference paths only. Under ``torch.compile`` the check
    (a host-side comparison) is not traced: ``compute`` runs inside the compiled graph,
    from the current tensors (so a captured CUDA graph replays it too).

    Examples:
        >>> import torch
        >>> weight = torch.ones(3)
        >>> calls = []
        >>> cache = VersionedCache(lambda: [weight], lambda: calls.append(1) or weight * 2)
        >>> _ = cache.get(); _ = cache.get()
        >>> len(calls)
        1
        >>> _ = weight.add_(1.0)  # an in-place change: recomputed
        >>> cache.get(), len(calls)
        (tensor([4., 4., 4.]), 2)
    """

    def __init__(
        self,
        sources: Callable[[], list[Tensor]],
        compute: Callable[[], T],
        probe: Callable[[], list[Tensor]] | None = None,
    ) -> None:
        self.sources = sources
        self.compute = compute
        self.probe = probe or sources
        self._tensors: list[Tensor] = []
        self._probed: list[tuple[Tensor, int]] = []
        self._versions: list[int] | None = None
        self._value: T | None = None

    def _valid(self) -> bool:
        if self._versions is None:
            return False
        probed = self.probe()
        if len(probed) != len(self._probed) or any(
            a is not b or a.data_ptr() != ptr
            for a, (b, ptr) in zip(probed, self._probed, strict=True)
        ):
            return False
        return [t._version for t in self._tensors] == self._versions

    def get(self) -> T:
        if torch.compiler.is_compiling():
            with torch.no_grad():
                return self.compute()
        if not self._valid():
            self._tensors = list(self.sources())
            self._probed = [(t, t.data_ptr()) for t in self.probe()]
            with torch.no_grad():
                self._value = self.compute()
            self._versions = [t._version for t in self._tensors]
        return self._value
