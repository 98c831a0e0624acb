"""Adam as every trainer of this package builds it: PyTorch's fused kernel.

``torch.optim.Adam(fused=True)`` updates every parameter of a group in one kernel (on the
CPU and on CUDA) instead of a dozen ATen calls per parameter tensor; the same arithmetic
in another order, so results differ from the per-parameter loop in the last bits only
(speed wins). A checkpoint keeps the group's ``fused`` flag.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch

import torchrl_dual._versioned_cache  # noqa: F401  (its step hook: fused steps move counters)


def adam(params: Iterable[torch.Tensor], lr: float, *, fuse: bool = True) -> torch.optim.Adam:
    """``torch.optim.Adam(params, lr)``, fused where it can be.

    Fused when ``fuse`` and every parameter is a floating-point tensor on the CPU or
    CUDA, else PyTorch's default implementation.

    Every optimizer this package builds is one of these: :func:`train_planner`'s,
    :func:`progressive_distillation`'s and every optimizer of the recipe's algorithms.
    PyTorch's fused Adam changes the weights without moving
    their version counters; the step hook of :mod:`torchrl_dual._versioned_cache` moves
    them, so the acting path's caches see every step. ``fuse=False`` keeps PyTorch's
    default. ``foreach=True`` fails under ``compile.compile=true`` (Dynamo: "Expected
    scalars to be on CPU, got meta" in ``_foreach_addcdiv_``), hence not used.

    Example:
        >>> import torch
        >>> optimizer = adam(torch.nn.Linear(3, 2).parameters(), lr=1e-3)
        >>> optimizer.param_groups[0]["fused"]
        True
    """
    params = list(params)
    if not fuse:
        return torch.optim.Adam(params, lr=lr)
    fused = bool(params) and all(
        p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in params
    )
    return torch.optim.Adam(params, lr=lr, fused=fused or None)
