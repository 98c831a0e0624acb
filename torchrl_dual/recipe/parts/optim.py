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

    ``fuse=False``: DUAL's actor optimizer. Fused, the resumed run of
    ``tests/recipe/test_algorithm_contract.py`` differs from the whole run in its state
    (not understood yet); ``foreach=True`` resumes bitwise but fails under
    ``compile.compile=true`` (Dynamo: "Expected scalars to be on CPU, got meta" in
    ``_foreach_addcdiv_``, ``tests/recipe/test_compile_recipe.py``)."""
    params = list(params)
    if not fuse:
        return torch.optim.Adam(params, lr=lr)
    fused = bool(params) and all(
        p.device.type in ("cpu", "cuda") and p.is_floating_point() for p in params
    )
    return torch.optim.Adam(params, lr=lr, fused=fused or None)
