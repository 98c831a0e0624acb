"""Per-dimension standardisation of states and actions, fitted on offline data."""

from __future__ import annotations

import torch
from torch import nn


class Normalizer(nn.Module):
    """Standardises observations and actions with statistics of the offline data.

    The statistics are buffers, so they are saved and restored with the model's
    ``state_dict`` and follow ``.to(device)``. A normalizer must be fitted (:meth:`fit`, or
    a fitted ``state_dict`` loaded) before it normalises anything: the unfitted statistics
    (mean 0, std 1) would silently train and sample in raw units, so every
    ``normalize_*`` / ``denormalize_*`` call before then raises.

    Args:
        obs_dim (int): state dimension.
        action_dim (int): action dimension.

    Keyword Args:
        eps (float): floor on the standard deviation (constant dimensions, such as
            a goal that never moves, would otherwise divide by zero). Defaults to ``1e-3``.

    Examples:
        >>> import torch
        >>> norm = Normalizer(obs_dim=3, action_dim=1)
        >>> obs, act = torch.randn(100, 3) * 5 + 2, torch.rand(100, 1)
        >>> _ = norm.fit(obs, act)
        >>> torch.allclose(norm.denormalize_observation(norm.normalize_observation(obs)), obs, atol=1e-5)
        True
        >>> Normalizer(obs_dim=3, action_dim=1).normalize_action(act)
        Traceback (most recent call last):
        ...
        RuntimeError: Normalizer is not fitted: call normalizer.fit(observations, actions) on the offline data (a planner's is model.normalizer) or load a fitted state_dict first.
    """

    def __init__(self, obs_dim: int, action_dim: int, *, eps: float = 1e-3) -> None:
        super().__init__()
        self.eps = eps
        self.register_buffer("obs_mean", torch.zeros(obs_dim))
        self.register_buffer("obs_std", torch.ones(obs_dim))
        self.register_buffer("action_mean", torch.zeros(action_dim))
        self.register_buffer("action_std", torch.ones(action_dim))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))
        self._fitted = False  # host copy of ``fitted``: checking it never syncs a device
        self.register_load_state_dict_post_hook(_refresh_fitted)

    def check_fitted(self) -> None:
        """Raises unless :meth:`fit` ran or a fitted ``state_dict`` was loaded."""
        if not self._fitted:
            raise RuntimeError(
                "Normalizer is not fitted: call normalizer.fit(observations, actions) on the "
                "offline data (a planner's is model.normalizer) or load a fitted state_dict "
                "first."
            )

    @torch.no_grad()
    def fit(self, observation: torch.Tensor, action: torch.Tensor) -> Normalizer:
        """Sets mean and standard deviation from ``[N, dim]`` samples; returns ``self``."""
        for name, value, buffer in (
            ("observation", observation, self.obs_mean),
            ("action", action, self.action_mean),
        ):
            if value.ndim != 2 or value.shape[-1] != buffer.shape[-1]:
                raise ValueError(
                    f"Normalizer.fit expects {name} of shape [N, {buffer.shape[-1]}], "
                    f"got {tuple(value.shape)}."
                )
            if not torch.isfinite(value).all():
                bad = int((~torch.isfinite(value)).sum())
                raise ValueError(f"{name} holds {bad} NaN/inf entries; clean the data set first.")
        observation, action = observation.double(), action.double()
        self.obs_mean.copy_(observation.mean(0))
        self.obs_std.copy_(observation.std(0).clamp_min(self.eps))
        self.action_mean.copy_(action.mean(0))
        self.action_std.copy_(action.std(0).clamp_min(self.eps))
        self.fitted.fill_(True)
        self._fitted = True
        return self

    def normalize_observation(self, observation: torch.Tensor) -> torch.Tensor:
        """Standardises observations: ``(s - μ_s) / σ_s``, any ``[..., obs_dim]``.

        Raises:
            RuntimeError: the normalizer is not fitted.
        """
        self.check_fitted()
        return (observation - self.obs_mean) / self.obs_std

    def denormalize_observation(self, observation: torch.Tensor) -> torch.Tensor:
        """Maps standardised observations back to raw units, ``s σ_s + μ_s``, ``[..., obs_dim]``.

        Raises:
            RuntimeError: the normalizer is not fitted.
        """
        self.check_fitted()
        return observation * self.obs_std + self.obs_mean

    def normalize_action(self, action: torch.Tensor) -> torch.Tensor:
        """Standardises actions: ``(a - μ_a) / σ_a``, any ``[..., action_dim]``.

        Raises:
            RuntimeError: the normalizer is not fitted.
        """
        self.check_fitted()
        return (action - self.action_mean) / self.action_std

    def denormalize_action(self, action: torch.Tensor) -> torch.Tensor:
        """Maps standardised actions back to raw units: ``a σ_a + μ_a``, any ``[..., action_dim]``.

        Raises:
            RuntimeError: the normalizer is not fitted.
        """
        self.check_fitted()
        return action * self.action_std + self.action_mean


def _refresh_fitted(module: Normalizer, incompatible_keys) -> None:
    """After ``load_state_dict``: the host copy of ``fitted`` from the loaded buffer."""
    module._fitted = bool(module.fitted)
