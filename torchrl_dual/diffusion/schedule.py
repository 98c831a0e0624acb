"""Continuous-time variance-preserving noise schedules.

A schedule maps a diffusion time ``t ∈ [0, 1]`` to the signal and noise scales
``(α_t, σ_t)`` of the forward process ``z_t = α_t·x + σ_t·ε`` with
``α_t² + σ_t² = 1``. The paper's discrete process (Section 2.2,
``q(τ^n | τ^{n-1}) = N(√(1-β_n) τ^{n-1}, β_n I)``) is the same process
observed on the grid ``t_n = n / N``: ``ᾱ_n = α_{t_n}²``.

Working in continuous time lets one network be sampled with any number of
steps that divides ``N`` and is what progressive distillation (Salimans & Ho,
2022) needs, since each student halves the grid of its teacher.
"""

from __future__ import annotations

import math

import torch
from torch import nn

SCHEDULES = ("cosine", "linear")


class NoiseSchedule(nn.Module):
    """Variance-preserving schedule ``(α_t, σ_t)`` on ``t ∈ [0, 1]``.

    Args:
        kind (str): ``"cosine"`` (default; Nichol & Dhariwal 2021, ``α_t = cos(πt/2)``,
            which reaches pure noise exactly at ``t = 1``) or ``"linear"`` (the
            continuous limit of DDPM's linear ``β`` schedule, ``β ∈ [0.1, 20]``).

    Examples:
        >>> import torch
        >>> schedule = NoiseSchedule("cosine")
        >>> alpha, sigma = schedule(torch.tensor([0.0, 0.5, 1.0]))
        >>> torch.allclose(alpha**2 + sigma**2, torch.ones(3))
        True
        >>> float(alpha[-1]) < 1e-6
        True
    """

    def __init__(self, kind: str = "cosine") -> None:
        super().__init__()
        if kind not in SCHEDULES:
            raise ValueError(f"Unknown noise schedule {kind!r}; choose one of {SCHEDULES}.")
        self.kind = kind

    def alpha_sigma(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Returns ``(α_t, σ_t)`` with the shape of ``t``."""
        return _alpha_sigma(self.kind, t, torch)

    def scales_at(self, t: float) -> tuple[float, float]:
        """``(α_t, σ_t)`` at one time ``t``, as Python floats (no tensor, no device read).

        Examples:
            >>> [round(v, 4) for v in NoiseSchedule("cosine").scales_at(0.5)]
            [0.7071, 0.7071]
        """
        return _alpha_sigma(self.kind, float(t), math)

    def forward(self, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(α_t, σ_t)`` with the shape of ``t``, as :meth:`alpha_sigma`."""
        return self.alpha_sigma(t)

    def snr(self, t: torch.Tensor) -> torch.Tensor:
        """Signal-to-noise ratio ``α_t² / σ_t²`` (``inf`` at ``t = 0``)."""
        alpha, sigma = self.alpha_sigma(t)
        return alpha**2 / sigma**2

    def extra_repr(self) -> str:
        """The schedule's kind, shown in the module's ``repr``."""
        return f"kind={self.kind!r}"


def _alpha_sigma(kind: str, t, ops):
    """``(α_t, σ_t)`` of schedule ``kind``: one formula for tensors and floats.

    ``ops`` is ``torch`` (tensors) or ``math`` (floats).
    """
    if kind == "cosine":
        angle = t * (math.pi / 2)
        return ops.cos(angle), ops.sin(angle)
    beta_min, beta_max = 0.1, 20.0
    log_alpha_bar = -(beta_min * t + 0.5 * (beta_max - beta_min) * t**2)
    return ops.exp(0.5 * log_alpha_bar), ops.sqrt(-ops.expm1(log_alpha_bar))
