"""Numerical helpers of the last-layer Laplace fit.

A robust PSD eigendecomposition and the evidence maximiser over the prior precision.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

_F64 = torch.float64


def psd_eigh(G: Tensor) -> tuple[Tensor, Tensor]:
    """Symmetric eigendecomposition that never fails; eigenvalues below round-off set to 0.

    ``G`` is ``[p, p]`` or a batch ``[*K, p, p]`` (one decomposition per matrix).

    Examples:
        >>> import torch
        >>> g, U = psd_eigh(torch.eye(3, dtype=torch.float64))
        >>> g.tolist()
        [1.0, 1.0, 1.0]
    """
    p = G.shape[-1]
    eye = torch.eye(p, dtype=_F64, device=G.device)
    scale = G.diagonal(dim1=-2, dim2=-1).abs().amax(-1).clamp_min(1.0)[..., None, None]
    jitter = 0.0
    for _ in range(8):
        try:
            g, U = torch.linalg.eigh(G + jitter * scale * eye)
            break
        except RuntimeError:  # eigh did not converge: add jitter and retry
            jitter = 1e-12 if jitter == 0.0 else jitter * 100.0
    else:  # only for pathological matrices (tests/modules/laplace/test_laplace_numerics.py)
        g = torch.zeros(G.shape[:-1], dtype=_F64, device=G.device)
        U = eye.expand(G.shape).clone()
    # round-off can make the eigenvalues of a PSD matrix slightly negative / tiny
    tol = g.abs().amax(-1, keepdim=True) * p * torch.finfo(_F64).eps
    g = torch.where(g > tol, g, torch.zeros_like(g))
    return g, U


def evidence_maximiser(
    h: Tensor, sq_norm: Tensor, bounds: tuple[float, float], iters: int = 100
) -> float:
    """The ``λ`` maximising the Laplace evidence, clamped to ``bounds``.

    ``d log Z / d log λ = ½ (γ(λ) − λ‖θ*‖²)`` with ``γ(λ) = Σ h / (h + λ)`` (``h`` the
    eigenvalues of every ``G/σ_j²``); ``γ`` decreases and ``λ‖θ*‖²`` increases, so the
    maximiser is the unique root (MacKay's fixed point), found by bisection in ``log λ``.

    Examples:
        >>> import torch
        >>> h = torch.tensor([1.0, 4.0], dtype=torch.float64)
        >>> lam = evidence_maximiser(h, torch.tensor(1.0, dtype=torch.float64), (1e-6, 1e6))
        >>> abs(float((h / (h + lam)).sum()) - lam) < 1e-8  # γ(λ) = λ‖θ*‖²
        True
    """
    lo, hi = (math.log(v) for v in bounds)

    def slope(t: float) -> float:
        lam = math.exp(t)
        return float((h / (h + lam)).sum() - lam * sq_norm)

    if slope(lo) <= 0:
        return math.exp(lo)
    if slope(hi) >= 0:
        return math.exp(hi)
    for _ in range(iters):
        mid = 0.5 * (lo + hi)
        if slope(mid) > 0:
            lo = mid
        else:
            hi = mid
        if hi - lo < 1e-12:
            break
    return math.exp(0.5 * (lo + hi))
