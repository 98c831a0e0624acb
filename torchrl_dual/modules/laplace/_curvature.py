"""The curvature of the last-layer Laplace fit (Eq. 8): the weighted Gram matrix.

For DUAL's linear-Gaussian head ``y = W φ + b`` the generalised Gauss-Newton matrix of the
weighted MAP loss (Eq. 7) is its exact Hessian, block diagonal over outputs, and every
block is the one weighted Gram matrix ``G = Σ_i w_i φ̃_i φ̃_iᵀ`` of the augmented
features ``φ̃ = [φ, 1]``, divided by ``σ_j²``. With a squashed mean ``c_j(y_j)`` each
output's block weighs a sample by its squared Jacobian,
``G_j = Σ_i w_i J_ij² φ̃_i φ̃_iᵀ`` (``per_output_jacobian=True``).

:class:`LaplaceCurvature` holds the streaming part of :class:`LastLayerLaplace`
(``modules/laplace/last_layer_laplace.py``): :meth:`~LaplaceCurvature.accumulate` adds a
batch to the float64 ``G_raw``, ``sum_weights`` and ``count`` buffers, and
:meth:`~LaplaceCurvature.gram` returns ``G`` with the weights normalised to mean 1. The
buffers are registered by ``LastLayerLaplace.__init__`` (so its ``state_dict`` keys and
their order are those of the one class this mixin was split from).
"""

from __future__ import annotations

import torch
from torch import Tensor

from torchrl_dual.modules.laplace._checks import (
    checked_features_and_weights,
    checked_output_jacobian,
)

__all__ = ["LaplaceCurvature"]


class LaplaceCurvature:
    """Gram-matrix accumulation of :class:`LastLayerLaplace` (a mixin: not used alone).

    Examples:
        >>> import torch
        >>> from torchrl_dual.modules.laplace import LastLayerLaplace
        >>> la = LastLayerLaplace(2, 1)
        >>> la.accumulate(torch.ones(4, 2), weights=torch.full((4,), 3.0))
        >>> la.gram()  # the weights normalised to mean 1: Σ_i φ̃_i φ̃_iᵀ with φ̃ = [1, 1, 1]
        tensor([[4., 4., 4.],
                [4., 4., 4.],
                [4., 4., 4.]], dtype=torch.float64)
    """

    # registered by LastLayerLaplace.__init__
    in_features: int
    out_features: int
    per_output_jacobian: bool
    G_raw: Tensor
    sum_weights: Tensor
    count: Tensor
    fitted: Tensor
    _fitted_value: bool

    @torch.no_grad()
    def reset(self) -> None:
        """Drop all accumulated statistics and the fit."""
        self.G_raw.zero_()
        self.sum_weights.zero_()
        self.count.zero_()
        self.fitted.fill_(False)
        self._fitted_value = False

    @torch.no_grad()
    def accumulate(
        self, features: Tensor, weights: Tensor | None = None, jacobian: Tensor | None = None
    ) -> None:
        """Adds a batch's weighted Gram ``Σ_i w_i φ̃_i φ̃_iᵀ`` to the float64 buffer (``O(B d²)``).

        With ``per_output_jacobian=True``, adds ``Σ_i w_i J_ij² φ̃_i φ̃_iᵀ`` to each
        output's.

        Args:
            features: head inputs ``φ`` of shape ``[B, d]`` (any leading batch shape).
            weights: non-negative per-sample loss weights (e.g. IQL ``exp(β A)``) of shape
                ``[B]`` (the leading shape of ``features``); ``None`` means all ones. They
                are normalised to mean 1 over everything accumulated at :meth:`fit` time.
            jacobian: ``J [B, out]``, the derivative of each mean action component in its
                head output at the MAP (required with ``per_output_jacobian=True``, refused
                otherwise). It scales the Gram matrices, not the weight normalisation.
        """
        phi, w = checked_features_and_weights(features, weights, self.in_features)
        phi = phi.to(self.G_raw.device)
        w = None if w is None else w.to(self.G_raw.device)
        if self.per_output_jacobian:
            J = checked_output_jacobian(jacobian, features, self.out_features)
            J = J.to(self.G_raw.device)
        elif jacobian is not None:
            raise ValueError(
                "jacobian given to a LastLayerLaplace with one shared Gram matrix; build it "
                "with per_output_jacobian=True for a squashed mean."
            )
        if phi.shape[0] == 0:
            return
        phi = torch.cat([phi, phi.new_ones(phi.shape[0], 1)], dim=1)
        if self.per_output_jacobian:
            wJ2 = J.square() if w is None else J.square() * w[:, None]
            self.G_raw.add_(torch.einsum("bo,bp,bq->opq", wJ2, phi, phi))
            self.sum_weights.add_(phi.shape[0] if w is None else w.sum())
        elif w is None:
            self.G_raw.add_(phi.T @ phi)
            self.sum_weights.add_(phi.shape[0])
        else:
            self.G_raw.add_((phi * w[:, None]).T @ phi)
            self.sum_weights.add_(w.sum())
        self.count.add_(phi.shape[0])

    def gram(self) -> Tensor:
        """Weighted Gram matrix ``G``, weights normalised to mean 1, float64 ``[d+1, d+1]``.

        ``[out, d+1, d+1]``, one ``G_j`` per output, with
        ``per_output_jacobian=True``.
        """
        if self.count.item() == 0:
            raise RuntimeError("no features accumulated; call accumulate() before fit().")
        if self.sum_weights.item() <= 0:
            raise RuntimeError(
                "all accumulated weights are zero, so the weighted likelihood is empty; "
                "accumulate samples with positive weights."
            )
        G = self.G_raw * (self.count / self.sum_weights)
        return 0.5 * (G + G.transpose(-1, -2))
