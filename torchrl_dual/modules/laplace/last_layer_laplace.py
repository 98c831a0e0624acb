"""Closed-form last-layer Laplace approximation of the DUAL actor (Eq. 8, Thm. 3.3).

:class:`LastLayerLaplace` is the posterior ``N(θ*, Σ_j)`` of the linear head: its buffers,
the fit of Eq. 8 (one eigendecomposition of the Gram matrix), the covariance, sampling
``θ_j = θ*_j + S_j ε`` for the ensemble of Eq. 9, and the closed-form predictive variance.
Two concepts it is built from live beside it, as mixins over the same buffers:
``modules/laplace/_curvature.py`` (``LaplaceCurvature``: accumulating the weighted Gram
matrix, the Hessian of Eq. 8) and ``modules/laplace/_evidence.py`` (``LaplaceEvidence``:
the prior precision chosen by the evidence of Thm. 3.3, and the temperature).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch
from torch import Tensor, nn

from torchrl_dual.modules.laplace._checks import checked_head
from torchrl_dual.modules.laplace._curvature import LaplaceCurvature
from torchrl_dual.modules.laplace._evidence import LaplaceEvidence
from torchrl_dual.modules.laplace._numerics import psd_eigh

__all__ = ["LastLayerLaplace"]

_F64 = torch.float64


class LastLayerLaplace(LaplaceCurvature, LaplaceEvidence, nn.Module):
    r"""Last-layer Laplace approximation for a linear-Gaussian policy head (DUAL Eq. 8).

    The policy mean of DUAL's actor ends in a linear head ``y = W φ + b``
    (``W: [out, d]``, ``b: [out]``) trained with the weighted MAP actor loss of Eq. 7,
    ``π(a|s) = N(y, diag(σ²))``. Writing ``φ̃ = [φ, 1]`` and ``θ_j = [w_j, b_j]`` for
    output ``j``, the loss over the data ``D`` (a *sum*, the log-likelihood, not a mean) is

    .. math::

        L(θ) = \sum_i w_i \sum_j \frac{(y_{ij} - θ_j^\top φ̃_i)^2}{2σ_j^2}
               - \log p(θ), \qquad p(θ) = N(0, λ^{-1} I),

    with the critic weights ``w_i`` normalised to mean 1 over everything accumulated.
    The Laplace approximation of Eq. 8 is ``p(θ|D) ≈ N(θ*, Σ)`` with
    ``Σ = (∇²_θ L(θ*))^{-1}``. For this linear-Gaussian head the generalised Gauss-Newton
    matrix *is* the exact Hessian and it is block diagonal over outputs:

    .. math::

        P_j = Σ_j^{-1} = \frac{G}{σ_j^2} + λ I, \qquad
        G = \sum_i w_i φ̃_i φ̃_i^\top = U \operatorname{diag}(g) U^\top .

    One eigendecomposition of the shared ``(d+1)×(d+1)`` Gram matrix ``G`` gives every
    ``P_j = U diag(g/σ_j² + λ) Uᵀ``, its log-determinant, the sampling transform
    ``S_j = U diag((g/σ_j² + λ)^{-1/2})`` (so ``θ_j = θ*_j + S_j ε``, ``ε ~ N(0, I)``) and the
    epistemic variance of the head output ``φ̃ᵀ P_j^{-1} φ̃ = Σ_k (Uᵀφ̃)_k² / (g_k/σ_j² + λ)``.

    **Prior precision.** The paper uses a flat prior (``λ = 0``), which leaves ``P_j``
    singular whenever the features do not span ``R^{d+1}``; here ``λ`` is either fixed or,
    by default, chosen post hoc by maximising the Laplace evidence of Thm. 3.3 for the
    fixed MAP ``θ*`` (MacKay 1992; Immer et al. 2021). With ``P = out·(d+1)`` parameters,
    ``Z = exp(-L(θ*)) (2π)^{P/2} det(Σ)^{1/2}`` and
    ``log p(θ*) = (P/2) log(λ/2π) - (λ/2)‖θ*‖²`` give

    .. math::

        \log Z(λ) = \log p(D|θ^*) + \frac{P}{2}\log λ - \frac{λ}{2}\|θ^*\|^2
                    - \frac12 \sum_j \sum_k \log\!\left(\frac{g_k}{σ_j^2} + λ\right).

    Its derivative in ``log λ`` is ``½ (γ(λ) - λ‖θ*‖²)`` with the effective number of
    parameters ``γ(λ) = Σ_{j,k} (g_k/σ_j²) / (g_k/σ_j² + λ)``; ``γ`` decreases and
    ``λ‖θ*‖²`` increases with ``λ``, so the maximiser is the unique root of MacKay's
    fixed-point equation ``λ = γ(λ)/‖θ*‖²``, found by bisection in ``log λ`` inside
    ``prior_precision_bounds`` (clamped to the bracket if the root lies outside).

    **Temperature.** ``temperature=T`` (a positive float) scales the posterior covariance,
    ``Σ_j = T·P_j^{-1}``, with ``λ`` chosen as at ``T = 1`` (a tempered posterior: ``T > 1``
    widens it). ``temperature="data"`` is the paper's literal Eq. 7, whose loss is an
    *expectation* over the data: the Laplace is taken over the mean loss, so the likelihood
    term of ``P_j`` is divided by the number of accumulated samples ``N``,
    ``P_j = G/(N σ_j²) + λ I`` (``λ`` by the evidence of that loss, or the fixed value), a
    posterior about ``N`` times wider than the summed loss's.

    **A squashed mean (generalised Gauss-Newton).** When the Gaussian sits *after* a
    fixed element-wise map of the head output, ``π(a|s) = N(c_j(y_j), σ_j²)`` (CORL's and
    d3rlpy's IQL actor: ``c_j(y) = center_j + r_j tanh(y)``), the Gauss-Newton Hessian of
    output ``j`` weighs each sample by the squared Jacobian ``J_ij = c_j'(y_ij)`` at the
    MAP: ``G_j = Σ_i w_i J_ij² φ̃_i φ̃_iᵀ``, one Gram matrix and one eigendecomposition per
    output (``per_output_jacobian=True``; :meth:`accumulate` then takes ``jacobian``). Every
    formula above holds with ``G_j = U_j diag(g_j) U_jᵀ`` in place of the shared ``G``.

    All statistics are float64. Eigenvalues of ``G`` below round-off are clamped to 0, so
    ``P_j ⪰ λ I`` is always invertible (e.g. for ``d + 1 > N``). Everything needed to
    sample, predict or refit (``G_raw``, weight sums, ``θ*``, ``λ``, ``σ²``, ``U``, ``g`` and the
    per-output scales of ``S_j``) is a registered buffer, so ``state_dict()`` round-trips;
    to refit, :meth:`accumulate` more data (or :meth:`reset` and re-accumulate) and call
    :meth:`fit` again, which costs one ``(d+1)×(d+1)`` eigendecomposition.

    Args:
        in_features: feature dimension ``d`` of the head input ``φ``.
        out_features: output dimension of the head (the action dimension).
        prior_precision: ``"evidence"`` (default) to maximise ``log Z(λ)`` at each fit, or a
            positive float used as is.
        prior_precision_bounds: bracket ``(λ_min, λ_max)`` for the evidence search.
        temperature: ``T`` (a positive float: ``Σ_j = T·P_j^{-1}``; default ``1.0``) or
            ``"data"`` (the Laplace of the mean loss, see above).
        per_output_jacobian: one Gram matrix per output, weighted by the squared
            Jacobian of a squashed mean (see above). Defaults to ``False`` (one shared
            ``G``: the mean is the head output itself, up to a constant scale).

    Examples:
        >>> import torch
        >>> from torchrl_dual.modules.laplace.last_layer_laplace import LastLayerLaplace
        >>> head = torch.nn.Linear(8, 2)
        >>> la = LastLayerLaplace(8, 2)
        >>> phi = torch.randn(256, 8)
        >>> la.accumulate(phi, weights=torch.rand(256))
        >>> la = la.fit(head.weight, head.bias, noise_variance=0.1)
        >>> la.sample(16).shape
        torch.Size([16, 2, 9])
        >>> W, b = la.weight_samples_split(16)
        >>> (torch.einsum("mod,bd->mbo", W, phi) + b[:, None]).shape
        torch.Size([16, 256, 2])
        >>> la.predictive_variance(phi).shape
        torch.Size([256, 2])
    """

    G_raw: Tensor
    sum_weights: Tensor
    count: Tensor
    theta_map: Tensor
    noise_variance: Tensor
    prior_precision: Tensor
    eigenvalues: Tensor
    eigenvectors: Tensor
    sample_scale: Tensor
    fitted: Tensor

    def __init__(
        self,
        in_features: int,
        out_features: int,
        prior_precision: str | float = "evidence",
        prior_precision_bounds: tuple[float, float] = (1e-6, 1e6),
        temperature: str | float = 1.0,
        per_output_jacobian: bool = False,
    ) -> None:
        super().__init__()
        if int(in_features) < 1 or int(out_features) < 1:
            raise ValueError(
                f"in_features and out_features must be >= 1, got {in_features} and "
                f"{out_features}; pass the head's weight.shape[1] and weight.shape[0]."
            )
        self.in_features = int(in_features)
        self.out_features = int(out_features)
        self.prior_precision_config = self._check_prior_config(prior_precision)
        lo, hi = (float(v) for v in prior_precision_bounds)
        if not (0.0 < lo < hi < math.inf):
            raise ValueError(
                f"prior_precision_bounds must satisfy 0 < low < high < inf, got {(lo, hi)}; "
                "e.g. use (1e-6, 1e6)."
            )
        self.prior_precision_bounds = (lo, hi)
        self.temperature = self._check_temperature(temperature)
        self._head_dtype = torch.float32

        self.per_output_jacobian = bool(per_output_jacobian)
        p, o = self.in_features + 1, self.out_features
        grams = (o,) if self.per_output_jacobian else ()  # G_j per output, or one shared G
        self.register_buffer("G_raw", torch.zeros(*grams, p, p, dtype=_F64))
        self.register_buffer("sum_weights", torch.zeros((), dtype=_F64))
        self.register_buffer("count", torch.zeros((), dtype=_F64))
        self.register_buffer("theta_map", torch.zeros(o, p, dtype=_F64))
        self.register_buffer("noise_variance", torch.ones(o, dtype=_F64))
        self.register_buffer("prior_precision", torch.ones((), dtype=_F64))
        self.register_buffer("eigenvalues", torch.zeros(*grams, p, dtype=_F64))
        self.register_buffer("eigenvectors", torch.eye(p, dtype=_F64).expand(*grams, p, p).clone())
        self.register_buffer("sample_scale", torch.ones(o, p, dtype=_F64))
        self.register_buffer("fitted", torch.zeros((), dtype=torch.bool))
        self._fitted_value = False  # host copy of ``fitted``: acting never reads the device
        self.register_load_state_dict_post_hook(_refresh_fitted)

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_linear(cls, linear: nn.Linear, **kwargs) -> LastLayerLaplace:
        """Build an (unfitted) approximation sized for ``linear``; kwargs go to ``__init__``."""
        return cls(linear.in_features, linear.out_features, **kwargs)

    def extra_repr(self) -> str:
        """The fit's settings, shown in the module's ``repr``."""
        return (
            f"in_features={self.in_features}, out_features={self.out_features}, "
            f"prior_precision={self.prior_precision_config!r}, temperature={self.temperature!r}"
            + (", per_output_jacobian=True" if self.per_output_jacobian else "")
        )

    def get_extra_state(self) -> dict:
        """The dtype of the head the posterior was fitted for, saved with the state dict."""
        return {"head_dtype": str(self._head_dtype).removeprefix("torch.")}

    def set_extra_state(self, state: dict) -> None:
        """Restores the head's dtype saved by :meth:`get_extra_state` (float32 if absent).

        Args:
            state (dict): ``{"head_dtype": str}``.
        """
        self._head_dtype = getattr(torch, state.get("head_dtype", "float32"))

    def _apply(self, fn: Callable[[Tensor], Tensor], recurse: bool = True):
        # Keep the float64 statistics float64 under ``.float()``/``.to(dtype)``: re-transfer
        # the original tensor (device change only) instead of a lossy dtype cast.
        def keep_f64(t: Tensor) -> Tensor:
            out = fn(t)
            if t.dtype == _F64 and out.dtype != _F64:
                out = t.to(device=out.device)
            return out

        return super()._apply(keep_f64, recurse)

    # ---------------------------------- accumulation: reset, accumulate, gram (_curvature.py)
    # ------------------------------------------------------------------ fit
    @torch.no_grad()
    def fit(
        self,
        weight: Tensor,
        bias: Tensor,
        noise_variance: Tensor | float,
        prior_precision: str | float | None = None,
    ) -> LastLayerLaplace:
        """Store the MAP head and compute the posterior ``N(θ*, P_j^{-1})`` of Eq. 8.

        Args:
            weight: MAP head weight ``W``, shape ``[out, d]``; its dtype is the dtype of
                :meth:`sample`.
            bias: MAP head bias ``b``, shape ``[out]``.
            noise_variance: policy variance ``σ²`` (per output ``[out]``, or a scalar).
            prior_precision: overrides the constructor's setting for this fit
                (``"evidence"`` or a positive float); ``None`` uses the constructor's.

        Returns:
            ``self``.
        """
        dev = self.G_raw.device
        theta, sigma2 = checked_head(
            weight, bias, noise_variance, self.out_features, self.in_features
        )
        theta, sigma2 = theta.to(dev, _F64), sigma2.to(dev, _F64)
        config = (
            self.prior_precision_config
            if prior_precision is None
            else self._check_prior_config(prior_precision)
        )

        g, U = psd_eigh(self.gram())  # one decomposition per output's G_j, or the shared G
        self.theta_map.copy_(theta)
        self.noise_variance.copy_(sigma2)
        self.eigenvalues.copy_(g)
        self.eigenvectors.copy_(U)
        if config == "evidence":
            lam = self._evidence_argmax()
        else:
            lam = torch.tensor(float(config), dtype=_F64, device=dev)
        self.prior_precision.copy_(lam)
        scale = self._precision_eigenvalues(lam).rsqrt() * math.sqrt(self._covariance_scale())
        self.sample_scale.copy_(scale)
        self._head_dtype = weight.dtype if weight.is_floating_point() else torch.float32
        self.fitted.fill_(True)
        self._fitted_value = True
        return self

    @property
    def is_fitted(self) -> bool:
        """Whether :meth:`fit` has run (the ``fitted`` buffer, read from a host copy)."""
        return self._fitted_value

    def _check_fitted(self, what: str) -> None:
        if not self.is_fitted:
            raise RuntimeError(
                f"LastLayerLaplace.{what}() called before fit(); call accumulate(features, "
                "weights) on the data and then fit(weight, bias, noise_variance)."
            )

    # ------------------------------------------------------------------ diagnostics
    # (log_evidence of Thm. 3.3 and the eigenvalues of P_j: _evidence.py)
    def posterior_precision(self) -> Tensor:
        """The posterior precisions ``Σ_j^{-1} = (κ G/σ_j² + λ I) / T`` (Eq. 8).

        Float64 ``[out, d+1, d+1]``; ``κ = T = 1`` at the default temperature.
        """
        self._check_fitted("posterior_precision")
        U = self._bases()[1]
        eigenvalues = self._precision_eigenvalues(self.prior_precision) / self._covariance_scale()
        return (U * eigenvalues[:, None, :]) @ U.transpose(-1, -2)

    def posterior_covariance(self) -> Tensor:
        """``Σ_j = T·P_j^{-1}`` as float64 ``[out, d+1, d+1]``."""
        self._check_fitted("posterior_covariance")
        S = self.sample_transform
        return S @ S.transpose(-1, -2)

    @property
    def sample_transform(self) -> Tensor:
        """``S_j = U diag(√T (κ g/σ_j² + λ)^{-1/2})`` (``S_j S_jᵀ = Σ_j``), float64 ``[out, d+1, d+1]``."""
        self._check_fitted("sample_transform")
        return self._bases()[1] * self.sample_scale[:, None, :]

    # ------------------------------------------------------------------ sampling
    def sample(
        self,
        num_samples: int,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
    ) -> Tensor:
        """Draw ``θ^{(m)}_j = θ*_j + S_j ε``, ``ε ~ N(0, I)``, independently per output.

        Args:
            num_samples: number of posterior samples ``M``.
            generator: optional generator (on the module's device) for reproducibility.
            dtype: output dtype; defaults to the dtype of the head passed to :meth:`fit`.

        Returns:
            ``[M, out, d+1]`` samples of ``[W | b]`` (last column = bias).
        """
        self._check_fitted("sample")
        if int(num_samples) < 0:
            raise ValueError(f"num_samples must be >= 0, got {num_samples}.")
        eps = torch.randn(
            int(num_samples),
            *self.sample_scale.shape,
            generator=generator,
            dtype=_F64,
            device=self.G_raw.device,
        )
        if self.per_output_jacobian:  # S_j ε = U_j (s_j ⊙ ε), one basis per output
            deviation = torch.einsum("mop,oqp->moq", eps * self.sample_scale, self.eigenvectors)
        else:  # S_j ε = U (s_j ⊙ ε): one [M·out, d+1] x [d+1, d+1] matmul
            deviation = (eps * self.sample_scale) @ self.eigenvectors.T
        theta = self.theta_map + deviation
        return theta.to(dtype or self._head_dtype)

    def weight_samples_split(
        self,
        num_samples: int,
        generator: torch.Generator | None = None,
        dtype: torch.dtype | None = None,
    ) -> tuple[Tensor, Tensor]:
        """:meth:`sample` split into ``W: [M, out, d]`` and ``b: [M, out]`` for a batched forward."""
        theta = self.sample(num_samples, generator=generator, dtype=dtype)
        return theta[..., :-1], theta[..., -1]

    # ------------------------------------------------------------------ prediction
    def predictive_variance(self, features: Tensor) -> Tensor:
        """Epistemic variance ``φ̃ᵀ Σ_j φ̃`` of the head output, closed form.

        Args:
            features: head inputs of shape ``[B, d]`` (any leading batch shape).

        Returns:
            ``[B, out]`` variances in the dtype of ``features``.
        """
        self._check_fitted("predictive_variance")
        if features.ndim < 1 or features.shape[-1] != self.in_features:
            raise ValueError(
                f"features must have shape [B, {self.in_features}], got {tuple(features.shape)}."
            )
        phi = features.to(self.G_raw.device, _F64)
        phi = torch.cat([phi, phi.new_ones(*phi.shape[:-1], 1)], dim=-1)
        if self.per_output_jacobian:  # z_j = U_jᵀ φ̃ per output
            z = torch.einsum("...p,opq->...oq", phi, self.eigenvectors)
            var = (z.square() * self.sample_scale.square()).sum(-1)
        else:
            var = (phi @ self.eigenvectors).square() @ self.sample_scale.square().T
        out_dtype = features.dtype if features.is_floating_point() else self._head_dtype
        return var.to(out_dtype)

    forward = predictive_variance


def _refresh_fitted(module: LastLayerLaplace, incompatible_keys) -> None:
    """After ``load_state_dict``: the host copy of ``fitted`` from the loaded buffer."""
    module._fitted_value = bool(module.fitted)
