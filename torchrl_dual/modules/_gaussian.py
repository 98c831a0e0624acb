"""The diagonal-Gaussian log-density used on the action path (no Distribution object)."""

from __future__ import annotations

import math

import torch

_HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


def gaussian_log_prob(value: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """``log N(value; loc, diag(scale²))`` summed over the last dimension.

    Examples:
        >>> import torch
        >>> x, mu, sd = torch.randn(3, 2), torch.zeros(3, 2), torch.ones(3, 2)
        >>> ref = torch.distributions.Normal(mu, sd).log_prob(x).sum(-1)
        >>> torch.allclose(gaussian_log_prob(x, mu, sd), ref)
        True
    """
    return (-0.5 * ((value - loc) / scale) ** 2 - scale.log() - _HALF_LOG_2PI).sum(-1)
