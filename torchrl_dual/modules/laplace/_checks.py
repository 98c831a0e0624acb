"""Input checks of the last-layer Laplace fit, each failure naming its fix."""

from __future__ import annotations

import math

import torch
from torch import Tensor

_F64 = torch.float64


def checked_features_and_weights(
    features: Tensor, weights: Tensor | None, in_features: int
) -> tuple[Tensor, Tensor | None]:
    """Checked features ``φ [N, d]`` and weights ``w [N]`` (float64) for a Laplace fit.

    They come from a batch of head inputs and per-sample loss weights (``w`` may be
    ``None``); anything wrong raises an error that says what it is and how to fix it.

    Examples:
        >>> import torch
        >>> phi, w = checked_features_and_weights(torch.randn(4, 3), torch.ones(4), 3)
        >>> phi.shape, w.dtype
        (torch.Size([4, 3]), torch.float64)
    """
    if not isinstance(features, Tensor):
        raise TypeError(f"features must be a torch.Tensor, got {type(features).__name__}.")
    if features.ndim < 1 or features.shape[-1] != in_features:
        raise ValueError(
            f"features must have shape [B, {in_features}] (last dim = in_features), "
            f"got {tuple(features.shape)}; pass the input of the linear head."
        )
    if features.ndim == 1:
        features = features.unsqueeze(0)
    if not features.is_floating_point():
        raise TypeError(f"features must be floating point, got {features.dtype}.")
    if weights is not None:
        if not isinstance(weights, Tensor):
            weights = torch.as_tensor(weights)
        if weights.shape != features.shape[:-1]:
            raise ValueError(
                f"weights must have shape {tuple(features.shape[:-1])} (one per feature "
                f"row), got {tuple(weights.shape)}; squeeze a trailing singleton dim."
            )
    phi = features.detach().reshape(-1, in_features).to(_F64)
    if not torch.isfinite(phi).all():
        raise ValueError(
            "features contain NaN or inf; check the network producing the head input "
            "(or filter those samples) before calling accumulate()."
        )
    if weights is None:
        return phi, None
    w = weights.detach().reshape(-1).to(phi.device, _F64)
    if not torch.isfinite(w).all():
        raise ValueError(
            "weights contain NaN or inf; clip the advantage weights (e.g. exp(β·A) "
            "clamped to a maximum) before calling accumulate()."
        )
    if (w < 0).any():
        raise ValueError(
            f"weights must be non-negative, got min {w.min().item():.3g}; use "
            "likelihood weights such as exp(β·A), not raw advantages."
        )
    return phi, w


def checked_head(
    weight: Tensor, bias: Tensor | None, noise_variance: Tensor | float, out: int, d: int
) -> tuple[Tensor, Tensor]:
    """``(θ* = [W | b] [out, d+1], σ² [out])`` in float64 from the MAP head, or an error.

    Examples:
        >>> import torch
        >>> theta, sigma2 = checked_head(torch.ones(2, 3), torch.zeros(2), 0.5, 2, 3)
        >>> theta.shape, sigma2.tolist()
        (torch.Size([2, 4]), [0.5, 0.5])
    """
    if weight.shape != (out, d):
        raise ValueError(
            f"weight must have shape [out, d] = {[out, d]}, got {list(weight.shape)}; "
            "pass the nn.Linear head's .weight."
        )
    if bias is None or bias.shape != (out,):
        got = None if bias is None else list(bias.shape)
        raise ValueError(
            f"bias must have shape [{out}], got {got}; for a bias-free head pass zeros."
        )
    theta = torch.cat([weight.detach(), bias.detach()[:, None]], dim=1).to(_F64)
    if not torch.isfinite(theta).all():
        raise ValueError("weight/bias contain NaN or inf; the MAP head has diverged.")
    sigma2 = torch.as_tensor(noise_variance).detach().to(theta.device, _F64)
    if sigma2.ndim > 1 or sigma2.numel() not in (1, out):
        raise ValueError(
            f"noise_variance must be a float or a tensor of shape [{out}] (variance, not "
            f"std, per action dim), got shape {list(sigma2.shape)}."
        )
    sigma2 = sigma2.reshape(-1).expand(out).clone()
    if not (torch.isfinite(sigma2).all() and (sigma2 > 0).all()):
        raise ValueError(
            f"noise_variance must be positive and finite, got {sigma2.tolist()}; pass "
            "σ² = exp(2·log_std) of the actor."
        )
    return theta, sigma2


def checked_output_jacobian(jacobian: Tensor | None, features: Tensor, out: int) -> Tensor:
    """The per-sample, per-output Jacobian ``J [N, out]`` (float64) of the mean action, checked.

    The Jacobian in the head output, for a Gram matrix per output
    (``per_output_jacobian=True``), or an error.

    Examples:
        >>> import torch
        >>> checked_output_jacobian(torch.ones(4, 2), torch.randn(4, 3), 2).shape
        torch.Size([4, 2])
    """
    if jacobian is None:
        raise ValueError(
            "this LastLayerLaplace has per_output_jacobian=True: pass jacobian=J, the "
            f"[B, {out}] derivative of each mean action component in its head output "
            "(e.g. r·(1 − tanh²(u)) after a tanh squash)."
        )
    jacobian = torch.as_tensor(jacobian)
    expected = (*features.shape[:-1], out)
    if tuple(jacobian.shape) != expected:
        raise ValueError(
            f"jacobian must have shape {list(expected)} (one row per feature row, one "
            f"column per output), got {list(jacobian.shape)}."
        )
    J = jacobian.detach().reshape(-1, out).to(_F64)
    if not torch.isfinite(J).all():
        raise ValueError("jacobian contains NaN or inf; check the squash's derivative.")
    return J


def word_or_positive(value: str | float, name: str, word: str, bad_number: str) -> str | float:
    """``value`` as a float if it is a positive finite number, or ``word`` itself.

    Anything else is a ``ValueError`` naming ``name`` (``bad_number`` for a number out
    of range).

    Examples:
        >>> word_or_positive(2, "temperature", "data", "must be positive")
        2.0
    """
    if isinstance(value, str):
        if value != word:
            raise ValueError(f"{name} must be {word!r} or a positive float, got {value!r}.")
        return value
    number = float(value)
    if not (0.0 < number < math.inf):
        raise ValueError(bad_number)
    return number
