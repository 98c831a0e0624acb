"""normalized_score: 100 * (R - R_random) / (R_expert - R_random) with clear errors."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from torchrl_dual.data import normalized_score


def test_random_maps_to_zero_and_expert_to_one_hundred():
    assert normalized_score(10.0, 10.0, 30.0) == 0.0
    assert normalized_score(30.0, 10.0, 30.0) == 100.0
    assert normalized_score(20, 10.0, 30.0) == 50.0


def test_arrays_and_tensors_keep_their_type_and_shape():
    out = normalized_score(np.array([[0.0, 50.0]]), 0.0, 100.0)
    assert isinstance(out, np.ndarray) and out.shape == (1, 2)
    t = normalized_score(torch.tensor([0.0, 200.0]), 0.0, 100.0)
    assert torch.equal(t, torch.tensor([0.0, 200.0]))


def test_equal_or_swapped_references_raise():
    with pytest.raises(ValueError, match="must be greater than random_return"):
        normalized_score(1.0, 5.0, 5.0)
    with pytest.raises(ValueError, match="swapped"):
        normalized_score(1.0, 100.0, 0.0)


def test_non_finite_or_non_numeric_inputs_raise():
    with pytest.raises(ValueError, match="random_return must be finite"):
        normalized_score(1.0, float("nan"), 1.0)
    with pytest.raises(ValueError, match="expert_return must be a real number"):
        normalized_score(1.0, 0.0, None)
    with pytest.raises(ValueError, match="2 NaN/inf entries"):
        normalized_score(np.array([np.nan, np.inf, 1.0]), 0.0, 1.0)
    with pytest.raises(ValueError, match="returns must be a number"):
        normalized_score([1.0, 2.0], 0.0, 1.0)
