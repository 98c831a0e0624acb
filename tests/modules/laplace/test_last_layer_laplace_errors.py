"""``LastLayerLaplace``'s error messages in full (``modules/laplace/last_layer_laplace.py``):
each names the call or value at fault and what to do, before and after a fit."""

from __future__ import annotations

import re

import pytest
import torch

from torchrl_dual.modules import LastLayerLaplace


def _exact(message: str) -> str:
    return "^" + re.escape(message) + "$"


@pytest.mark.parametrize(
    ("call", "name"),
    [
        (lambda la: la.log_evidence(1.0), "log_evidence"),
        (lambda la: la.posterior_precision(), "posterior_precision"),
        (lambda la: la.posterior_covariance(), "posterior_covariance"),
        (lambda la: la.sample_transform(), "sample_transform"),
        (lambda la: la.sample(2), "sample"),
        (lambda la: la.predictive_variance(torch.randn(3, 2)), "predictive_variance"),
    ],
)
def test_every_posterior_query_before_fit_names_itself_and_the_two_calls(call, name):
    laplace = LastLayerLaplace(2, 1)
    with pytest.raises(
        RuntimeError,
        match=_exact(
            f"LastLayerLaplace.{name}() called before fit(); call accumulate(features, weights) "
            "on the data and then fit(weight, bias, noise_variance)."
        ),
    ):
        call(laplace)


def test_construction_errors_name_the_fix():
    with pytest.raises(
        ValueError,
        match=_exact(
            "in_features and out_features must be >= 1, got 0 and 2; pass the head's "
            "weight.shape[1] and weight.shape[0]."
        ),
    ):
        LastLayerLaplace(0, 2)
    with pytest.raises(
        ValueError,
        match=_exact(
            "prior_precision_bounds must satisfy 0 < low < high < inf, got (1.0, 1.0); "
            "e.g. use (1e-6, 1e6)."
        ),
    ):
        LastLayerLaplace(2, 1, prior_precision_bounds=(1.0, 1.0))


def test_fit_errors_name_the_fix():
    laplace = LastLayerLaplace(2, 1)
    with pytest.raises(
        RuntimeError, match=_exact("no features accumulated; call accumulate() before fit().")
    ):
        laplace.fit(torch.randn(1, 2), torch.zeros(1), 1.0)
    laplace.accumulate(torch.randn(4, 2), torch.zeros(4))
    with pytest.raises(
        RuntimeError,
        match=_exact(
            "all accumulated weights are zero, so the weighted likelihood is empty; accumulate "
            "samples with positive weights."
        ),
    ):
        laplace.fit(torch.randn(1, 2), torch.zeros(1), 1.0)
    with pytest.raises(
        ValueError,
        match=_exact(
            "jacobian given to a LastLayerLaplace with one shared Gram matrix; build it with "
            "per_output_jacobian=True for a squashed mean."
        ),
    ):
        laplace.accumulate(torch.randn(4, 2), torch.ones(4), jacobian=torch.ones(4, 1))


def test_query_errors_after_a_fit_name_the_fix():
    laplace = LastLayerLaplace(2, 1, prior_precision=1.0)
    laplace.accumulate(torch.randn(8, 2))
    laplace.fit(torch.randn(1, 2), torch.zeros(1), 0.5)
    with pytest.raises(ValueError, match=_exact("num_samples must be >= 0, got -1.")):
        laplace.sample(-1)
    assert laplace.sample(0).shape[0] == 0
    with pytest.raises(ValueError, match=_exact("features must have shape [B, 2], got (3, 4).")):
        laplace.predictive_variance(torch.randn(3, 4))
