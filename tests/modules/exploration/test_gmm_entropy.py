"""Tests of the batched Gaussian-mixture fit and DACER's entropy estimate
(``torchrl_dual/modules/exploration/gmm_entropy.py``): EM against known mixtures, the
estimate against closed forms (one Gaussian; ``Σ_k w_k H_k + H(w)`` for separated
components; a Monte-Carlo mixture entropy), its behaviour under scaling and translation,
and the covariance floor on a point mass."""

from __future__ import annotations

import math

import pytest
import torch

from torchrl_dual.modules.exploration import (
    GaussianMixtureFit,
    fit_gaussian_mixture,
    mixture_entropy,
)

LOG_2PI_E = 1 + math.log(2 * math.pi)

# three well-separated 2-D components with distinct weights and correlated covariances
WEIGHTS = torch.tensor([0.2, 0.3, 0.5], dtype=torch.float64)
MEANS = torch.tensor([[-8.0, 0.0], [0.0, 8.0], [8.0, -2.0]], dtype=torch.float64)
COVARIANCES = torch.tensor(
    [[[1.0, 0.5], [0.5, 1.0]], [[0.5, 0.0], [0.0, 2.0]], [[1.5, -0.6], [-0.6, 0.8]]],
    dtype=torch.float64,
)


def gaussian_entropy(covariance: torch.Tensor) -> torch.Tensor:
    """``½ log((2πe)^A |Σ|)``, the closed form."""
    dim = covariance.shape[-1]
    return 0.5 * (dim * LOG_2PI_E + torch.logdet(covariance))


def sample_mixture(n: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``n`` samples of the mixture above (exact counts ``n · w_k``) and their labels."""
    gen = torch.Generator().manual_seed(seed)
    counts = (WEIGHTS * n).round().long().tolist()
    chol = torch.linalg.cholesky(COVARIANCES)
    parts, labels = [], []
    for k, count in enumerate(counts):
        z = torch.randn(count, 2, generator=gen, dtype=torch.float64)
        parts.append(MEANS[k] + z @ chol[k].T)
        labels.append(torch.full((count,), k))
    order = torch.randperm(sum(counts), generator=gen)
    return torch.cat(parts)[order], torch.cat(labels)[order]


def by_first_mean(fit: GaussianMixtureFit, entry: int = 0):
    """The fit's components of ``entry`` ordered like ``MEANS`` (by the first coordinate)."""
    order = fit.means[entry, :, 0].argsort()
    return fit.weights[entry, order], fit.means[entry, order], fit.covariances[entry, order]


def test_em_recovers_the_weights_means_and_covariances_of_separated_components():
    x, _ = sample_mixture(3000, seed=0)
    fit = fit_gaussian_mixture(x[None])
    weights, means, covariances = by_first_mean(fit)
    torch.testing.assert_close(weights, WEIGHTS, atol=1e-3, rtol=0)  # separated: exact counts
    torch.testing.assert_close(means, MEANS, atol=0.12, rtol=0)
    torch.testing.assert_close(covariances, COVARIANCES, atol=0.15, rtol=0)
    assert torch.allclose(fit.weights.sum(-1), torch.ones(1, dtype=torch.float64))


def test_the_fit_of_a_batch_is_the_fit_of_each_entry_and_keeps_the_input_dtype():
    a, _ = sample_mixture(600, seed=1)
    b = 0.5 * torch.randn(600, 2, generator=torch.Generator().manual_seed(2)).double()
    both = fit_gaussian_mixture(torch.stack([a, b]).float())
    assert both.means.dtype == torch.float32 and both.means.shape == (2, 3, 2)
    for entry, x in enumerate((a, b)):
        alone = fit_gaussian_mixture(x[None].float())
        torch.testing.assert_close(both.means[entry], alone.means[0])
        torch.testing.assert_close(both.covariances[entry], alone.covariances[0])


def test_one_component_is_the_closed_form_entropy_of_the_sample_covariance():
    """``C = 1``: EM is the maximum-likelihood Gaussian, so the estimate is
    ``½ log((2πe)^A |S|)`` of the (biased) sample covariance ``S``, and within sampling
    error of the true Gaussian's entropy."""
    gen = torch.Generator().manual_seed(3)
    cov = torch.tensor([[0.04, 0.01, 0.0], [0.01, 0.09, 0.02], [0.0, 0.02, 0.25]])
    x = (
        torch.randn(8, 500, 3, generator=gen, dtype=torch.float64)
        @ torch.linalg.cholesky(cov.double()).T
    )
    centred = x - x.mean(-2, keepdim=True)
    sample_cov = centred.transpose(-1, -2) @ centred / x.shape[-2]
    estimate = mixture_entropy(x, num_components=1, covariance_floor=1e-12)
    torch.testing.assert_close(estimate, gaussian_entropy(sample_cov), atol=1e-8, rtol=0)
    truth = gaussian_entropy(cov.double())
    # the std of a 3-D log-determinant over 500 samples is about sqrt(2 * 3 / 500) / 2 = 0.055
    assert (estimate - truth).abs().max() < 0.25
    assert abs(float(estimate.mean() - truth)) < 0.06


def test_three_components_on_one_gaussian_overestimate_its_entropy_by_a_bounded_amount():
    """DACER's default ``C = 3`` splits a single Gaussian into overlapping pieces; the
    estimate is then an upper bound, measured at about +0.5 nats in 2-D (K = 200)."""
    x = 0.3 * torch.randn(64, 200, 2, generator=torch.Generator().manual_seed(4))
    truth = 2 * (0.5 * LOG_2PI_E + math.log(0.3))
    gap = float(mixture_entropy(x).mean()) - truth
    assert 0.1 < gap < 0.8, gap


def test_separated_components_give_the_weighted_entropies_plus_the_label_entropy():
    x, _ = sample_mixture(3000, seed=5)
    estimate = float(mixture_entropy(x[None])[0])
    closed_form = float(
        (WEIGHTS * gaussian_entropy(COVARIANCES)).sum() - (WEIGHTS * WEIGHTS.log()).sum()
    )
    assert abs(estimate - closed_form) < 0.05, (estimate, closed_form)
    # ... which is the mixture's entropy itself when the components do not overlap:
    # −E log p(x) of the true mixture by Monte Carlo on fresh samples
    true_fit = GaussianMixtureFit(WEIGHTS[None], MEANS[None], COVARIANCES[None])
    fresh, _ = sample_mixture(20000, seed=6)
    monte_carlo = float(-true_fit.log_prob(fresh[None]).mean())
    assert abs(monte_carlo - closed_form) < 0.03, (monte_carlo, closed_form)


@pytest.mark.parametrize("covariance_type", ["full", "diag"])
def test_scaling_the_samples_by_c_shifts_the_estimate_by_a_log_c_and_translation_not_at_all(
    covariance_type,
):
    x, _ = sample_mixture(900, seed=7)
    x = x[None].float()
    base = mixture_entropy(x, covariance_type=covariance_type, covariance_floor=1e-9)
    for c in (0.1, 3.0):
        scaled = mixture_entropy(c * x, covariance_type=covariance_type, covariance_floor=1e-9)
        torch.testing.assert_close(scaled, base + 2 * math.log(c), atol=1e-4, rtol=0)
    moved = mixture_entropy(x + torch.tensor([5.0, -3.0]), covariance_type=covariance_type)
    torch.testing.assert_close(moved, base, atol=1e-4, rtol=0)


def test_diag_covariances_are_diagonal_and_never_below_the_full_estimate():
    """The diagonal fit drops the correlations: each component's diagonal Gaussian has
    at least the entropy of the full one with the same variances (Hadamard's inequality)."""
    x, _ = sample_mixture(1500, seed=8)
    diag = fit_gaussian_mixture(x[None], covariance_type="diag")
    full = fit_gaussian_mixture(x[None], covariance_type="full")
    off_diagonal = diag.covariances - torch.diag_embed(diag.covariances.diagonal(dim1=-2, dim2=-1))
    assert off_diagonal.abs().max() == 0
    assert float(diag.entropy()[0]) > float(full.entropy()[0]) + 0.05  # correlated data


def test_a_point_mass_keeps_the_finite_entropy_of_the_covariance_floor():
    """Actions clamped to a corner of the box: every sample equal. Each component's
    covariance is the floor ``ε I``, so the estimate is ``½ A (log 2πe + log ε)``."""
    x = torch.ones(2, 50, 2)
    estimate = mixture_entropy(x, covariance_floor=1e-6)
    expected = 0.5 * 2 * (LOG_2PI_E + math.log(1e-6))
    # the components coincide: the weights' entropy adds at most log 3
    assert torch.isfinite(estimate).all()
    assert (estimate >= expected - 1e-4).all() and (estimate <= expected + math.log(3)).all()
    alone = mixture_entropy(x, num_components=1, covariance_floor=1e-6)
    torch.testing.assert_close(alone, torch.full((2,), expected), atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"covariance_type": "spherical"}, "unknown covariance_type 'spherical'"),
        ({"num_components": 5}, "needs K >= num_components >= 1"),
        ({"covariance_floor": 0.0}, "covariance_floor must be > 0"),
    ],
)
def test_bad_arguments_raise_one_clear_error(kwargs, message):
    with pytest.raises(ValueError, match=message):
        fit_gaussian_mixture(torch.randn(2, 4, 2), **kwargs)
