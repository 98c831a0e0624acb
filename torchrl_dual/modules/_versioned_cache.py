"""A value derived from tensors, recomputed only when one of them changes."""

from __future__ import annotations

from collections.abc import Callable
from typing import Generic, TypeVar

import torch
from torch import Tensor

T = TypeVar("T")


class VersionedCache(Generic[T]):
    """Caches ``compute()`` until one of ``sources()`` is modified or replaced.

    A tensor counts as changed when its storage (``data_ptr``) or its version counter
    (bumped by every in-place operation: optimizer steps, ``copy_`` in
    ``load_state_dict``, ...) differs from the last call. ``sources`` is called each
    time, so tensors replaced by ``.to()`` or ``.double()`` are seen too. ``compute`` runs
    without autograd: use the cache on inference paths only.

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

    def __init__(self, sources: Callable[[], list[Tensor]], compute: Callable[[], T]) -> None:
        self.sources = sources
        self.compute = compute
        self._key: list | None = None
        self._value: T | None = None

    def get(self) -> T:
        key = [(t.data_ptr(), t._version) for t in self.sources()]
        if key != self._key:
            with torch.no_grad():
                self._value = self.compute()
            self._key = key
        return self._value
