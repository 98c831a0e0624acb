"""Tests of the last-layer Laplace fit's input checks (``modules/laplace/_checks.py``):
what each accepts and returns (float64, shapes), and each error's whole message, since
the message is the fix the user reads."""

from __future__ import annotations

import re

import pytest
import torch

from torchrl_dual.modules.laplace._checks import (
    checked_features_and_weights,
    checked_head,
    checked_output_jacobian,
    word_or_positive,
)


def _exact(message: str) -> str:
    return "^" + re.escape(message) + "$"


# ----------------------------------------------------------------------------- features
def test_features_and_weights_come_back_flat_in_float64():
    features = torch.randn(2, 3, 4)
    phi, w = checked_features_and_weights(features, torch.ones(2, 3), 4)
    assert phi.dtype == w.dtype == torch.float64
    assert phi.shape == (6, 4) and w.shape == (6,)
    torch.testing.assert_close(phi, features.reshape(6, 4).double())
    phi, none = checked_features_and_weights(features, None, 4)
    assert none is None and phi.shape == (6, 4)


def test_one_feature_row_is_a_batch_of_one():
    phi, w = checked_features_and_weights(torch.arange(3.0), torch.tensor([2.0]), 3)
    assert phi.shape == (1, 3) and phi.tolist() == [[0.0, 1.0, 2.0]] and w.tolist() == [2.0]


def test_weights_may_be_a_list_and_zero_but_not_negative():
    phi, w = checked_features_and_weights(torch.randn(3, 2), [0.0, 1.0, 2.5], 2)
    assert w.tolist() == [0.0, 1.0, 2.5] and w.dtype == torch.float64
    with pytest.raises(
        ValueError,
        match=_exact(
            "weights must be non-negative, got min -1; use likelihood weights such as "
            "exp(β·A), not raw advantages."
        ),
    ):
        checked_features_and_weights(torch.randn(3, 2), torch.tensor([1.0, -1.0, 0.0]), 2)


def test_feature_errors_name_the_fix():
    with pytest.raises(TypeError, match=_exact("features must be a torch.Tensor, got list.")):
        checked_features_and_weights([[1.0, 2.0]], None, 2)
    with pytest.raises(
        ValueError,
        match=_exact(
            "features must have shape [B, 3] (last dim = in_features), got (4, 2); pass the "
            "input of the linear head."
        ),
    ):
        checked_features_and_weights(torch.randn(4, 2), None, 3)
    with pytest.raises(ValueError, match=r"got \(\); pass"):
        checked_features_and_weights(torch.tensor(1.0), None, 1)
    with pytest.raises(
        TypeError, match=_exact("features must be floating point, got torch.int64.")
    ):
        checked_features_and_weights(torch.ones(2, 3, dtype=torch.long), None, 3)
    with pytest.raises(
        ValueError,
        match=_exact(
            "weights must have shape (2, 3) (one per feature row), got (2, 3, 1); squeeze a "
            "trailing singleton dim."
        ),
    ):
        checked_features_and_weights(torch.randn(2, 3, 4), torch.ones(2, 3, 1), 4)
    bad = torch.randn(2, 3)
    bad[1, 2] = float("nan")
    with pytest.raises(
        ValueError,
        match=_exact(
            "features contain NaN or inf; check the network producing the head input (or "
            "filter those samples) before calling accumulate()."
        ),
    ):
        checked_features_and_weights(bad, None, 3)
    with pytest.raises(
        ValueError,
        match=_exact(
            "weights contain NaN or inf; clip the advantage weights (e.g. exp(β·A) clamped to "
            "a maximum) before calling accumulate()."
        ),
    ):
        checked_features_and_weights(torch.randn(2, 3), torch.tensor([1.0, float("inf")]), 3)


# ----------------------------------------------------------------------------- head
def test_the_head_is_weight_and_bias_side_by_side_in_float64():
    weight, bias = torch.randn(2, 3), torch.randn(2)
    theta, sigma2 = checked_head(weight, bias, torch.tensor([0.5, 2.0]), 2, 3)
    assert theta.dtype == sigma2.dtype == torch.float64
    torch.testing.assert_close(theta, torch.cat([weight, bias[:, None]], 1).double())
    assert sigma2.tolist() == [0.5, 2.0]
    assert checked_head(weight, bias, 0.25, 2, 3)[1].tolist() == [0.25, 0.25]


def test_head_errors_name_the_fix():
    with pytest.raises(
        ValueError,
        match=_exact(
            "weight must have shape [out, d] = [2, 3], got [3, 2]; pass the nn.Linear head's "
            ".weight."
        ),
    ):
        checked_head(torch.randn(3, 2), torch.zeros(2), 1.0, 2, 3)
    with pytest.raises(
        ValueError,
        match=_exact("bias must have shape [2], got None; for a bias-free head pass zeros."),
    ):
        checked_head(torch.randn(2, 3), None, 1.0, 2, 3)
    with pytest.raises(
        ValueError,
        match=_exact("bias must have shape [2], got [3]; for a bias-free head pass zeros."),
    ):
        checked_head(torch.randn(2, 3), torch.zeros(3), 1.0, 2, 3)
    weight = torch.randn(2, 3)
    weight[0, 0] = float("inf")
    with pytest.raises(
        ValueError, match=_exact("weight/bias contain NaN or inf; the MAP head has diverged.")
    ):
        checked_head(weight, torch.zeros(2), 1.0, 2, 3)
    with pytest.raises(
        ValueError,
        match=_exact(
            "noise_variance must be a float or a tensor of shape [2] (variance, not std, per "
            "action dim), got shape [2, 1]."
        ),
    ):
        checked_head(torch.randn(2, 3), torch.zeros(2), torch.ones(2, 1), 2, 3)
    with pytest.raises(ValueError, match=r"got shape \[3\]\.$"):
        checked_head(torch.randn(2, 3), torch.zeros(2), torch.ones(3), 2, 3)
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="^noise_variance must be positive and finite, got "):
            checked_head(torch.randn(2, 3), torch.zeros(2), bad, 2, 3)
    with pytest.raises(
        ValueError, match=re.escape("got [0.0, 0.0]; pass σ² = exp(2·log_std) of the actor.") + "$"
    ):
        checked_head(torch.randn(2, 3), torch.zeros(2), 0.0, 2, 3)


# ----------------------------------------------------------------------------- jacobian
def test_the_jacobian_is_flattened_to_one_row_per_feature_row():
    J = checked_output_jacobian(torch.ones(2, 3, 4), torch.randn(2, 3, 5), 4)
    assert J.shape == (6, 4) and J.dtype == torch.float64


def test_jacobian_errors_name_the_fix():
    with pytest.raises(
        ValueError,
        match=_exact(
            "this LastLayerLaplace has per_output_jacobian=True: pass jacobian=J, the [B, 2] "
            "derivative of each mean action component in its head output (e.g. r·(1 − tanh²(u)) "
            "after a tanh squash)."
        ),
    ):
        checked_output_jacobian(None, torch.randn(4, 3), 2)
    with pytest.raises(
        ValueError,
        match=_exact(
            "jacobian must have shape [4, 2] (one row per feature row, one column per output), "
            "got [4, 3]."
        ),
    ):
        checked_output_jacobian(torch.ones(4, 3), torch.randn(4, 3), 2)
    with pytest.raises(
        ValueError, match=_exact("jacobian contains NaN or inf; check the squash's derivative.")
    ):
        checked_output_jacobian(torch.tensor([[1.0, float("nan")]]), torch.randn(1, 3), 2)


def test_word_or_positive():
    assert word_or_positive("data", "t", "data", "bad") == "data"
    assert word_or_positive(3, "t", "data", "bad") == 3.0
    with pytest.raises(
        ValueError, match=_exact("t must be 'data' or a positive float, got 'dta'.")
    ):
        word_or_positive("dta", "t", "data", "bad")
    for bad in (0, -1.0, float("inf")):
        with pytest.raises(ValueError, match=_exact("must be positive")):
            word_or_positive(bad, "t", "data", "must be positive")
