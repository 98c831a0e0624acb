"""``LastLayerLaplace(temperature=...)`` (issue 29): a tempered posterior and the paper's
literal expectation form, against closed forms and an autograd Hessian."""

from __future__ import annotations

import pytest
import torch

from torchrl_dual.modules import LastLayerLaplace

D, OUT, N = 5, 2, 400


def fitted(temperature, prior_precision="evidence") -> LastLayerLaplace:
    torch.manual_seed(0)
    phi = torch.randn(N, D, dtype=torch.float64)
    weights = torch.rand(N, dtype=torch.float64) * 2
    head = torch.nn.Linear(D, OUT).double()
    laplace = LastLayerLaplace(D, OUT, prior_precision=prior_precision, temperature=temperature)
    laplace.accumulate(phi, weights)
    return laplace.fit(head.weight.detach(), head.bias.detach(), torch.tensor([0.09, 0.25]))


@pytest.mark.parametrize("temperature", [0.5, 3.0, 100.0])
def test_a_temperature_scales_the_covariance_exactly_and_keeps_the_evidence_prior(temperature):
    base, tempered = fitted(1.0), fitted(temperature)
    assert tempered.prior_precision.item() == base.prior_precision.item()  # λ as at T = 1
    torch.testing.assert_close(
        tempered.posterior_covariance(), temperature * base.posterior_covariance()
    )
    torch.testing.assert_close(
        tempered.posterior_precision(), base.posterior_precision() / temperature
    )
    phi = torch.randn(7, D, dtype=torch.float64)
    torch.testing.assert_close(
        tempered.predictive_variance(phi), temperature * base.predictive_variance(phi)
    )
    spread = tempered.sample(20000, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    empirical = torch.stack([torch.cov(spread[:, j].T) for j in range(OUT)])
    want = tempered.posterior_covariance()
    relative = (empirical - want).flatten(1).norm(dim=1) / want.flatten(1).norm(dim=1)
    assert relative.max() < 0.05  # the draws have the tempered covariance


@pytest.mark.parametrize("prior_precision", ["evidence", 0.7])
def test_data_is_the_laplace_of_the_mean_loss_by_autograd(prior_precision):
    """``temperature="data"``: ``Σ^{-1}`` is the Hessian of
    ``(1/N) Σ_i w_i Σ_j (y_ij − θ_jᵀφ̃_i)² / (2σ_j²) + (λ/2)‖θ‖²`` (weights at mean 1)."""
    laplace = fitted("data", prior_precision)
    torch.manual_seed(0)  # the same data as fitted()
    phi = torch.randn(N, D, dtype=torch.float64)
    weights = torch.rand(N, dtype=torch.float64) * 2
    weights = weights / weights.mean()
    phi1 = torch.cat([phi, torch.ones(N, 1, dtype=torch.float64)], 1)
    sigma2 = torch.tensor([0.09, 0.25], dtype=torch.float64)
    lam = laplace.prior_precision.item()
    if prior_precision != "evidence":
        assert lam == prior_precision

    def mean_loss(theta: torch.Tensor) -> torch.Tensor:
        theta = theta.view(OUT, D + 1)
        residual = phi1 @ theta.T  # y = 0: the Hessian does not depend on the targets
        nll = (weights[:, None] * residual**2 / (2 * sigma2)).sum(1).mean()
        return nll + 0.5 * lam * theta.square().sum()

    hessian = torch.autograd.functional.hessian(
        mean_loss, torch.zeros(OUT * (D + 1), dtype=torch.float64)
    ).view(OUT, D + 1, OUT, D + 1)
    blocks = torch.stack([hessian[j, :, j, :] for j in range(OUT)])
    torch.testing.assert_close(laplace.posterior_precision(), blocks)
    assert hessian[0, :, 1, :].abs().max() == 0  # block diagonal over outputs
    # about N times wider than the summed-loss posterior at the same λ
    summed = fitted(1.0, lam)
    ratio = laplace.posterior_covariance().diagonal(
        dim1=-2, dim2=-1
    ) / summed.posterior_covariance().diagonal(dim1=-2, dim2=-1)
    assert 1 < ratio.min() and ratio.max() <= N + 1e-6


def test_a_bad_temperature_names_the_choices():
    with pytest.raises(ValueError, match="'data' or a positive float"):
        LastLayerLaplace(D, OUT, temperature="mean")
    with pytest.raises(ValueError, match="positive finite float"):
        LastLayerLaplace(D, OUT, temperature=0.0)
