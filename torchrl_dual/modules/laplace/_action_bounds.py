"""The optional action bounds of the ensemble policies (Eq. 9), kept where ``.to()`` moves them."""

from __future__ import annotations

import torch
from torch import nn


class ActionBounds:
    """Mixin of the Laplace ensembles: the action bounds and the clamp to them.

    Used by :class:`~torchrl_dual.modules.LaplaceEnsembleActor` and
    :class:`~torchrl_dual.modules.laplace.LatentEnsembleActor`: ``action_low`` and
    ``action_high`` (float, tensor or ``None``).

    Tensor bounds are registered as non-persistent buffers, so that ``policy.to(device)``
    moves them with the weights (a bound left on the CPU would fail the clamp of a CUDA
    action, or copy to the device at every step) and checkpoints keep their keys.
    """

    def _set_bounds(
        self: nn.Module,
        low: float | torch.Tensor | None,
        high: float | torch.Tensor | None,
    ) -> None:
        for name, value in (("action_low", low), ("action_high", high)):
            if isinstance(value, torch.Tensor):
                self.register_buffer(name, value.detach().clone(), persistent=False)
            else:
                setattr(self, name, value)

    def _clamp(self, action: torch.Tensor) -> torch.Tensor:
        """``action`` clamped to the bounds (unchanged without any)."""
        if self.action_low is None and self.action_high is None:
            return action
        return action.clamp(self.action_low, self.action_high)
