"""``LastLayerLaplace``'s dtypes, input shapes and saved state
(``modules/laplace/last_layer_laplace.py``), each against a posterior computed by hand in
the test: ``Σ_j = (G/σ_j² + λ I)^{-1}`` with ``G = Σ_i w_i φ̃_i φ̃_iᵀ`` (weights normalised to
mean 1) and the Laplace evidence ``(P/2) log λ − (λ/2)‖θ*‖² − ½ Σ_j log det P_j``."""

from __future__ import annotations

import io
import math
import re

import pytest
import torch
from torch import nn

from torchrl_dual.modules import LastLayerLaplace

F64 = torch.float64
D, OUT = 3, 2


def _data(seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    phi = torch.randn(40, D, generator=gen, dtype=F64)
    w = torch.rand(40, generator=gen, dtype=F64) + 0.5
    W = torch.randn(OUT, D, generator=gen, dtype=F64)
    b = torch.randn(OUT, generator=gen, dtype=F64)
    sigma2 = torch.tensor([0.3, 0.8], dtype=F64)
    return phi, w, W, b, sigma2


def _precision_by_hand(phi, w, sigma2, lam):
    """``P_j = G/σ_j² + λ I`` for every output, ``[out, d+1, d+1]``."""
    phit = torch.cat([phi, torch.ones(len(phi), 1, dtype=F64)], 1)
    wn = w / w.mean()
    G = (phit * wn[:, None]).T @ phit
    eye = torch.eye(phit.shape[1], dtype=F64)
    return torch.stack([G / s2 + lam * eye for s2 in sigma2])


def _variance_by_hand(features, phi, w, sigma2, lam):
    """``φ̃ᵀ P_j^{-1} φ̃`` of every row of ``features`` (float64), ``[*B, out]``."""
    cov = torch.linalg.inv(_precision_by_hand(phi, w, sigma2, lam))
    x = features.to(F64)
    x = torch.cat([x, torch.ones(*x.shape[:-1], 1, dtype=F64)], -1)
    return torch.einsum("...p,opq,...q->...o", x, cov, x)


def _fit(head_dtype=torch.float32, prior=0.7):
    phi, w, W, b, sigma2 = _data()
    la = LastLayerLaplace(D, OUT, prior_precision=prior)
    la.accumulate(phi, w)
    la.fit(W.to(head_dtype), b.to(head_dtype), sigma2)
    return la, phi, w, sigma2


def test_from_linear_sizes_the_approximation_for_the_layer_and_passes_the_options():
    la = LastLayerLaplace.from_linear(nn.Linear(5, 4), prior_precision=0.5, temperature="data")
    assert (la.in_features, la.out_features) == (5, 4)
    assert la.prior_precision_config == 0.5 and la.temperature == "data"
    assert la.theta_map.shape == (4, 6) and not la.is_fitted


def test_extra_repr_names_sizes_prior_and_temperature_and_a_per_output_jacobian_only_if_set():
    assert LastLayerLaplace(3, 2).extra_repr() == (
        "in_features=3, out_features=2, prior_precision='evidence', temperature=1.0"
    )
    assert LastLayerLaplace(
        4, 1, prior_precision=2, temperature="data", per_output_jacobian=True
    ).extra_repr() == (
        "in_features=4, out_features=1, prior_precision=2.0, temperature='data', "
        "per_output_jacobian=True"
    )


def test_the_head_dtype_survives_a_state_dict_round_trip():
    la, *_ = _fit(head_dtype=F64)
    assert la.sample(2).dtype == F64
    buffer = io.BytesIO()
    torch.save(la.state_dict(), buffer)
    buffer.seek(0)
    restored = LastLayerLaplace(D, OUT)
    restored.load_state_dict(torch.load(buffer, weights_only=True))
    assert restored.sample(2).dtype == F64
    assert restored.predictive_variance(torch.ones(1, D, dtype=torch.long)).dtype == F64


def test_a_saved_state_without_a_head_dtype_loads_as_float32():
    la, *_ = _fit(head_dtype=F64)
    la.set_extra_state({})  # e.g. a checkpoint written before the head dtype was saved
    assert la.sample(2).dtype == torch.float32


def test_only_float64_tensors_are_kept_under_a_dtype_cast():
    class WithFloat32Buffer(LastLayerLaplace):
        def __init__(self):
            super().__init__(D, OUT)
            self.register_buffer("extra", torch.zeros(3))

    module = WithFloat32Buffer().half()
    assert module.extra.dtype == torch.float16  # any other tensor follows the cast
    assert module.G_raw.dtype == F64 and module.theta_map.dtype == F64
    assert module.fitted.dtype == torch.bool


def test_evidence_lambda_solves_mackays_fixed_point_to_float64_precision():
    phi, w, W, b, sigma2 = _data(seed=3)
    la = LastLayerLaplace(D, OUT)
    la.accumulate(phi, w)
    la.fit(W, b, sigma2)
    lam = la.prior_precision.item()
    assert la.prior_precision.dtype == F64
    # γ(λ) = Σ_j Σ_k h_jk / (h_jk + λ), h the eigenvalues of G/σ_j², computed here
    h = torch.linalg.eigvalsh(_precision_by_hand(phi, w, sigma2, 0.0))
    gamma = (h / (h + lam)).sum().item()
    theta_sq = (W.square().sum() + b.square().sum()).item()
    assert 1e-6 < lam < 1e6
    assert abs(gamma / (lam * theta_sq) - 1.0) < 1e-10


def test_log_evidence_of_a_float32_sweep_is_float64_and_equals_the_closed_form():
    la, phi, w, sigma2 = _fit(head_dtype=F64)
    grid = torch.logspace(-2, 2, 9)  # float32 values of λ
    assert grid.dtype == torch.float32
    evidence = la.log_evidence(grid)  # default log_likelihood: 0
    assert evidence.dtype == F64 and evidence.shape == (9,)
    theta_sq = la.theta_map.square().sum()
    n_params = OUT * (D + 1)
    expected = torch.stack(
        [
            0.5 * n_params * math.log(lam)
            - 0.5 * lam * theta_sq
            - 0.5 * torch.logdet(_precision_by_hand(phi, w, sigma2, lam)).sum()
            for lam in grid.double().tolist()
        ]
    )
    torch.testing.assert_close(evidence, expected, rtol=1e-12, atol=1e-10)
    lam = 0.37  # a float, not representable in float32
    torch.testing.assert_close(
        la.log_evidence(lam),
        0.5 * n_params * math.log(lam)
        - 0.5 * lam * theta_sq
        - 0.5 * torch.logdet(_precision_by_hand(phi, w, sigma2, lam)).sum(),
        rtol=1e-12,
        atol=1e-10,
    )


def test_weight_samples_split_honours_the_requested_dtype():
    la, *_ = _fit(head_dtype=torch.float32)
    weight, bias = la.weight_samples_split(3, dtype=F64)
    assert weight.dtype == F64 and bias.dtype == F64
    assert weight.shape == (3, OUT, D) and bias.shape == (3, OUT)
    weight, bias = la.weight_samples_split(3)  # the head's dtype by default
    assert weight.dtype == torch.float32 and bias.dtype == torch.float32


def test_predictive_variance_of_one_feature_vector_and_of_a_nested_batch():
    la, phi, w, sigma2 = _fit()
    x = torch.randn(2, 4, D, generator=torch.Generator().manual_seed(1))
    nested = la.predictive_variance(x)
    assert nested.shape == (2, 4, OUT) and nested.dtype == torch.float32
    torch.testing.assert_close(nested.double(), _variance_by_hand(x, phi, w, sigma2, 0.7))
    single = la.predictive_variance(x[1, 2])
    assert single.shape == (OUT,)
    torch.testing.assert_close(single.double(), _variance_by_hand(x[1, 2], phi, w, sigma2, 0.7))


def test_predictive_variance_is_in_the_features_dtype_or_the_heads_for_integer_features():
    la, phi, w, sigma2 = _fit(head_dtype=torch.float32)
    x = torch.randn(5, D, dtype=F64, generator=torch.Generator().manual_seed(2))
    variance = la.predictive_variance(x)
    assert variance.dtype == F64  # float64 features over a float32 head
    torch.testing.assert_close(
        variance, _variance_by_hand(x, phi, w, sigma2, 0.7), rtol=1e-10, atol=0
    )
    integers = torch.tensor([[1, -2, 3], [0, 4, -1]])
    variance = la.predictive_variance(integers)
    assert variance.dtype == torch.float32  # the head's dtype, not int64
    torch.testing.assert_close(
        variance.double(), _variance_by_hand(integers, phi, w, sigma2, 0.7), rtol=1e-6, atol=0
    )


def test_all_statistics_are_float64_and_the_fit_flag_a_bool_false_before_fit():
    la = LastLayerLaplace(D, OUT)
    for name, buffer in la.named_buffers():
        assert buffer.dtype == (torch.bool if name == "fitted" else F64), name
    assert la.is_fitted is False and not bool(la.fitted)


def test_an_unfitted_modules_state_loads_into_another():
    state = LastLayerLaplace(D, OUT).state_dict()  # e.g. a checkpoint before the first fit
    restored = LastLayerLaplace(D, OUT)
    restored.load_state_dict(state)
    assert restored.is_fitted is False
    phi, w, W, b, sigma2 = _data()
    restored.accumulate(phi, w)
    restored.fit(W.float(), b.float(), sigma2)
    assert restored.sample(1).dtype == torch.float32


def test_a_one_feature_head_fits_the_closed_form_posterior():
    phi, w, W, b, sigma2 = _data()
    la = LastLayerLaplace(1, 1, prior_precision=0.7)
    la.accumulate(phi[:, :1], w)
    la.fit(W[:1, :1], b[:1], sigma2[:1])
    torch.testing.assert_close(
        la.posterior_precision(), _precision_by_hand(phi[:, :1], w, sigma2[:1], 0.7)
    )


def test_prior_precision_bounds_must_be_positive_and_finite():
    message = (
        "prior_precision_bounds must satisfy 0 < low < high < inf, got {}; e.g. use (1e-6, 1e6)."
    )
    for bounds in [(0.0, 1.0), (1.0, math.inf)]:
        with pytest.raises(ValueError, match="^" + re.escape(message.format(bounds)) + "$"):
            LastLayerLaplace(D, OUT, prior_precision_bounds=bounds)


def test_prior_precision_and_temperature_errors_name_the_argument_and_the_fix():
    cases = [
        (
            {"prior_precision": "map"},
            "prior_precision must be 'evidence' or a positive float, got 'map'.",
        ),
        (
            {"prior_precision": -1.0},
            "a fixed prior_precision must be a positive finite float, got -1.0; use "
            "prior_precision='evidence' to choose it from the data.",
        ),
        ({"temperature": "mean"}, "temperature must be 'data' or a positive float, got 'mean'."),
        (
            {"temperature": 0.0},
            "temperature must be a positive finite float (1.0: the summed-loss posterior) or "
            "'data' (the mean loss's), got 0.0.",
        ),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
            LastLayerLaplace(D, OUT, **kwargs)


def test_data_temperature_with_a_single_sample_divides_the_likelihood_by_one():
    phi, w, W, b, sigma2 = _data()
    la = LastLayerLaplace(D, OUT, prior_precision=0.7, temperature="data")
    la.accumulate(phi[:1])  # N = 1: P_j = G/(1·σ_j²) + λ I
    la.fit(W, b, sigma2)
    torch.testing.assert_close(
        la.posterior_precision(), _precision_by_hand(phi[:1], w[:1], sigma2, 0.7)
    )


def test_weights_summing_below_one_are_normalised_like_any_others():
    phi, w, W, b, sigma2 = _data()
    small = w / w.sum() * 0.5  # total weight 0.5
    la = LastLayerLaplace(D, OUT, prior_precision=0.7)
    la.accumulate(phi, small)
    la.fit(W, b, sigma2)
    torch.testing.assert_close(la.posterior_precision(), _precision_by_hand(phi, w, sigma2, 0.7))


def test_the_gram_matrix_is_exactly_symmetric_shared_or_per_output():
    phi, w, *_ = _data()
    shared = LastLayerLaplace(D, OUT)
    shared.accumulate(phi, w)
    jacobian = torch.rand(40, OUT, generator=torch.Generator().manual_seed(4), dtype=F64) + 0.1
    per_output = LastLayerLaplace(D, OUT, per_output_jacobian=True)
    per_output.accumulate(phi, w, jacobian=jacobian)
    for la in (shared, per_output):
        assert not torch.equal(la.G_raw, la.G_raw.mT)  # round-off in the accumulated sums
        G = la.gram()
        assert torch.equal(G, G.mT)
        torch.testing.assert_close(G, la.G_raw * (40 / w.sum()), rtol=1e-12, atol=1e-12)


def test_samples_are_the_map_plus_the_sample_transform_of_float64_normal_draws():
    for per_output_jacobian in (False, True):
        phi, w, W, b, sigma2 = _data()
        la = LastLayerLaplace(D, OUT, prior_precision=0.7, per_output_jacobian=per_output_jacobian)
        jacobian = torch.full((40, OUT), 0.5, dtype=F64) if per_output_jacobian else None
        la.accumulate(phi, w, jacobian=jacobian)
        la.fit(W, b, sigma2)
        samples = la.sample(4, generator=torch.Generator().manual_seed(5))
        eps = torch.randn(4, OUT, D + 1, generator=torch.Generator().manual_seed(5), dtype=F64)
        theta = torch.cat([W, b[:, None]], 1)
        expected = theta + torch.einsum("opq,moq->mop", la.sample_transform, eps)
        assert samples.dtype == F64
        torch.testing.assert_close(samples, expected, rtol=1e-12, atol=1e-12)
