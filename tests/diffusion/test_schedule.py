"""Tests of the variance-preserving noise schedules (``torchrl_dual/diffusion/schedule.py``)."""

from __future__ import annotations

import pytest
import torch

from torchrl_dual.diffusion import SCHEDULES, NoiseSchedule

GRID = torch.linspace(0.0, 1.0, 1001, dtype=torch.float64)


@pytest.mark.parametrize("kind", SCHEDULES)
def test_alpha_squared_plus_sigma_squared_is_one(kind):
    alpha, sigma = NoiseSchedule(kind)(GRID)
    torch.testing.assert_close(alpha**2 + sigma**2, torch.ones_like(GRID), atol=1e-12, rtol=0)


@pytest.mark.parametrize("kind", SCHEDULES)
def test_schedule_starts_clean_and_keeps_the_shape_of_t(kind):
    t = torch.rand(3, 5)
    alpha, sigma = NoiseSchedule(kind)(t)
    assert alpha.shape == sigma.shape == t.shape
    alpha0, sigma0 = NoiseSchedule(kind)(torch.zeros(()))
    assert float(alpha0) == 1.0 and float(sigma0) == 0.0


def test_cosine_schedule_reaches_pure_noise_at_t_one():
    alpha, sigma = NoiseSchedule("cosine")(torch.tensor([1.0], dtype=torch.float64))
    assert abs(float(alpha)) < 1e-15
    assert float(sigma) == 1.0


def test_linear_schedule_is_nearly_pure_noise_at_t_one():
    alpha, _ = NoiseSchedule("linear")(torch.tensor(1.0))
    assert 0.0 < float(alpha) < 0.01


@pytest.mark.parametrize("kind", SCHEDULES)
def test_snr_decreases_strictly_from_infinity_at_t_zero(kind):
    schedule = NoiseSchedule(kind)
    snr = schedule.snr(GRID)
    assert torch.isinf(snr[0])
    assert (snr[1:-1].diff() < 0).all()
    assert float(snr[-1]) < 1e-3


def test_unknown_schedule_name_error_lists_the_options():
    with pytest.raises(ValueError, match="sigmoid") as err:
        NoiseSchedule("sigmoid")
    for name in SCHEDULES:
        assert name in str(err.value)


def test_the_default_schedule_is_the_cosine_one():
    schedule = NoiseSchedule()
    assert schedule.kind == "cosine"
    t = torch.tensor([0.3])
    torch.testing.assert_close(schedule.alpha_sigma(t)[0], torch.cos(torch.pi * t / 2))


@pytest.mark.parametrize("kind", ["cosine", "linear"])
def test_scales_at_is_the_host_float_of_alpha_sigma(kind):
    """``scales_at(t)`` (a host float, for the compiled sampler's step constants) equals
    the tensor path at interior points."""
    schedule = NoiseSchedule(kind)
    for t in (0.1, 0.37, 0.5, 0.9):
        alpha, sigma = schedule.scales_at(t)
        assert isinstance(alpha, float) and isinstance(sigma, float)
        expected = schedule.alpha_sigma(torch.tensor(t, dtype=torch.float64))
        assert alpha == pytest.approx(float(expected[0]), rel=1e-12)
        assert sigma == pytest.approx(float(expected[1]), rel=1e-12)
