r"""The prior precision and temperature of the last-layer Laplace fit (Eq. 8, Thm. 3.3).

In the eigenbasis ``G_j = U_j diag(g_j) U_jᵀ`` of the Gram matrix
(``modules/laplace/_curvature.py``) the posterior precision of output ``j`` is diagonal,
``P_j = U_j diag(κ g_j/σ_j² + λ) U_jᵀ``, with ``κ = 1/N`` for ``temperature="data"`` (the
Laplace of Eq. 7's mean loss) and ``κ = 1`` otherwise; a float temperature ``T`` scales
the covariance, ``Σ_j = T·P_j^{-1}``. The Laplace log evidence of Thm. 3.3 for the fixed
MAP ``θ*`` (``P = out·(d+1)`` parameters, the ``2π`` terms cancelled) is

.. math::

    \log Z(λ) = \log p(D|θ^*) + \frac{P}{2}\log λ - \frac{λ}{2}\|θ^*\|^2
                - \frac12 \sum_j \sum_k \log(κ g_{jk}/σ_j^2 + λ),

and ``prior_precision="evidence"`` takes its maximiser, the root of MacKay's fixed point
``λ = γ(λ)/‖θ*‖²`` (``modules/laplace/_numerics.py``, ``evidence_maximiser``).

:class:`LaplaceEvidence` holds these eigenvalues, the evidence and its ``λ`` for
:class:`LastLayerLaplace` (``modules/laplace/last_layer_laplace.py``), and the checks of
the ``prior_precision`` and ``temperature`` settings.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from torchrl_dual.modules.laplace._checks import word_or_positive
from torchrl_dual.modules.laplace._numerics import evidence_maximiser

__all__ = ["LaplaceEvidence"]

_F64 = torch.float64


class LaplaceEvidence:
    """Prior precision, temperature and evidence of :class:`LastLayerLaplace` (a mixin).

    Examples:
        >>> import torch
        >>> from torchrl_dual.modules.laplace import LastLayerLaplace
        >>> _ = torch.manual_seed(0)
        >>> la = LastLayerLaplace(4, 2)
        >>> la.accumulate(torch.randn(64, 4))
        >>> la = la.fit(torch.randn(2, 4), torch.zeros(2), noise_variance=0.5)
        >>> lam = la.prior_precision  # the evidence maximiser: no other λ scores higher
        >>> bool(la.log_evidence(lam) >= la.log_evidence(torch.stack([lam / 2, lam * 2])).max())
        True
    """

    # registered by LastLayerLaplace.__init__
    per_output_jacobian: bool
    temperature: str | float
    prior_precision_bounds: tuple[float, float]
    G_raw: Tensor
    count: Tensor
    theta_map: Tensor
    noise_variance: Tensor
    eigenvalues: Tensor
    eigenvectors: Tensor
    _check_fitted: Callable[[str], None]

    @staticmethod
    def _check_prior_config(prior_precision: str | float) -> str | float:
        return word_or_positive(
            prior_precision,
            "prior_precision",
            "evidence",
            f"a fixed prior_precision must be a positive finite float, got {prior_precision}; "
            "use prior_precision='evidence' to choose it from the data.",
        )

    @staticmethod
    def _check_temperature(temperature: str | float) -> str | float:
        return word_or_positive(
            temperature,
            "temperature",
            "data",
            "temperature must be a positive finite float (1.0: the summed-loss posterior) "
            f"or 'data' (the mean loss's), got {temperature}.",
        )

    def _likelihood_scale(self) -> Tensor:
        """``κ`` of ``P_j = κ G/σ_j² + λ I``: ``1/N`` for ``temperature="data"``, else 1."""
        if self.temperature == "data":
            return 1.0 / self.count.clamp_min(1.0)
        return torch.ones((), dtype=_F64, device=self.G_raw.device)

    def _covariance_scale(self) -> float:
        """``T`` of ``Σ_j = T·P_j^{-1}`` (1 for ``temperature="data"``)."""
        return 1.0 if self.temperature == "data" else float(self.temperature)

    def _bases(self) -> tuple[Tensor, Tensor]:
        """``(g [K, d+1], U [K, d+1, d+1])`` with ``K = out`` per output or ``1`` shared."""
        if self.per_output_jacobian:
            return self.eigenvalues, self.eigenvectors
        return self.eigenvalues[None], self.eigenvectors[None]

    def _likelihood_eigenvalues(self) -> Tensor:
        """``κ g_jk/σ_j²``, ``[out, d+1]``."""
        g = self._bases()[0]
        return self._likelihood_scale() * g / self.noise_variance[:, None]

    def _precision_eigenvalues(self, lam: Tensor) -> Tensor:
        """Eigenvalues ``κ g_k/σ_j² + λ`` of ``P_j``; ``lam`` of shape ``[*L]`` -> ``[*L, out, d+1]``."""
        return self._likelihood_eigenvalues() + lam[..., None, None]

    def _evidence_argmax(self) -> Tensor:
        """The evidence-maximising ``λ`` for the current fit (see :func:`evidence_maximiser`)."""
        h = self._likelihood_eigenvalues()
        lam = evidence_maximiser(h, self.theta_map.square().sum(), self.prior_precision_bounds)
        return torch.tensor(lam, dtype=_F64, device=self.G_raw.device)

    def log_evidence(self, prior_precision: Tensor | float, log_likelihood: float = 0.0) -> Tensor:
        """Laplace log evidence ``log Z(λ)`` of Thm. 3.3 for the fitted ``θ*`` and ``σ²``.

        ``log Z(λ) = log p(D|θ*) + (P/2) log λ - (λ/2)‖θ*‖² - ½ Σ_j log det P_j(λ)`` (exact;
        the ``2π`` terms cancel). ``log p(D|θ*)`` does not depend on ``λ`` and is not
        stored; pass it as ``log_likelihood`` for the absolute value.

        Args:
            prior_precision: ``λ`` (float, or a tensor of any shape for a vectorised sweep).
            log_likelihood: the weighted log-likelihood ``log p(D|θ*)``; 0 by default.

        Returns:
            float64 tensor of the shape of ``prior_precision``.
        """
        self._check_fitted("log_evidence")
        lam = torch.as_tensor(prior_precision, dtype=_F64, device=self.G_raw.device)
        n_params = self.theta_map.numel()
        logdet = self._precision_eigenvalues(lam).log().sum(dim=(-2, -1))
        sq = self.theta_map.square().sum()
        return log_likelihood + 0.5 * n_params * lam.log() - 0.5 * lam * sq - 0.5 * logdet
