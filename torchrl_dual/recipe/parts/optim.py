"""The recipe's Adam: PyTorch's fused kernel (issue 40, item 2).

``torch.optim.Adam(fused=True)`` updates every parameter of a group in one kernel (on the
CPU and on CUDA) instead of a dozen ATen calls per parameter tensor; the same arithmetic
in another order, so results differ from the per-parameter loop in the last bits only
(the project's decision in issue 40: speed wins). A checkpoint keeps the group's
``fused`` flag: a run resumed from a checkpoint written before this steps as it did.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch


def adam(params: Iterable[torch.Tensor], lr: float, *, fuse: bool = True) -> torch.optim.Adam:
    """``torch.optim.Adam(params, lr)``, fused when ``fuse`` and every parameter is a
    floating-point tensor on the CPU or CUDA, else PyTorch's default implementation.

    ``fuse=False``: DUAL's actor optimizer, for now. Fused, the resumed run of
    ``tests/recipe/test_algorithm_contract.py`` differed from the whole run: PyTorch's
    fused Adam changes the weights without moving their version counters, so the acting
    path's caches kept serving the weights of before the step until the next refit, while
    a resumed run (weights loaded with ``copy_``) recomputed them. The step hook of
    :mod:`torchrl_dual._versioned_cache` now moves the counters, and the contract and
    compile tests pass with DUAL's actor fused (2026-12-06); it stays unfused until the
    DUAL runs the README cites are re-run on the fused update (issue 40's rule for a
    speed-up that changes results by rounding). ``foreach=True`` fails under
    ``compile.compile=true`` (Dynamo: "Expected scalars to be on CPU, got meta" in
    ``_foreach_addcdiv_``, ``tests/recipe/test_compile_recipe.py``)."""
    params = list(params)
    if not fuse:
        return torch.optim.Adam(params, lr=lr)
    fused = bool(params) and all(
        p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in params
    )
    return torch.optim.Adam(params, lr=lr, fused=fused or None)
