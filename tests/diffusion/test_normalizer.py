"""Tests of ``Normalizer`` (``torchrl_dual/diffusion/normalizer.py``)."""

from __future__ import annotations

import io

import pytest
import torch

from torchrl_dual.diffusion import Normalizer

pytestmark = pytest.mark.usefixtures("seeded")


def _data(n=200):
    return torch.randn(n, 3) * torch.tensor([5.0, 0.1, 2.0]) + 3.0, torch.rand(n, 2) * 4 - 1


def test_normalize_then_denormalize_is_the_identity():
    obs, act = _data()
    norm = Normalizer(3, 2).fit(obs, act)
    torch.testing.assert_close(norm.denormalize_observation(norm.normalize_observation(obs)), obs)
    torch.testing.assert_close(norm.denormalize_action(norm.normalize_action(act)), act)


def test_fitted_statistics_standardise_the_data():
    obs, act = _data()
    norm = Normalizer(3, 2).fit(obs, act)
    z = norm.normalize_observation(obs)
    torch.testing.assert_close(z.mean(0), torch.zeros(3), atol=1e-5, rtol=0)
    torch.testing.assert_close(z.std(0), torch.ones(3), atol=1e-5, rtol=0)
    assert bool(norm.fitted)


def test_a_constant_dimension_is_floored_at_eps_instead_of_dividing_by_zero():
    obs, act = _data()
    obs[:, 1] = 7.0
    norm = Normalizer(3, 2, eps=1e-3).fit(obs, act)
    assert float(norm.obs_std[1]) == pytest.approx(1e-3)
    assert torch.isfinite(norm.normalize_observation(obs)).all()


def test_statistics_are_saved_in_the_state_dict_and_restored():
    obs, act = _data()
    source = Normalizer(3, 2).fit(obs, act)
    buffer = io.BytesIO()
    torch.save(source.state_dict(), buffer)
    buffer.seek(0)
    target = Normalizer(3, 2)
    target.load_state_dict(torch.load(buffer, weights_only=True))
    assert {"obs_mean", "obs_std", "action_mean", "action_std", "fitted"} <= set(
        source.state_dict()
    )
    assert bool(target.fitted)
    assert torch.equal(target.normalize_observation(obs), source.normalize_observation(obs))
    assert torch.equal(target.normalize_action(act), source.normalize_action(act))


@pytest.mark.parametrize("which", ["observation", "action"])
def test_fit_on_nan_data_names_the_input_and_counts_the_bad_entries(which):
    obs, act = _data()
    bad = obs if which == "observation" else act
    bad[3, 0] = float("nan")
    bad[7, 1] = float("inf")
    with pytest.raises(ValueError, match=rf"{which} holds 2 NaN/inf entries"):
        Normalizer(3, 2).fit(obs, act)


def test_fit_with_the_wrong_dimension_shows_expected_and_given_shapes():
    obs, act = _data()
    with pytest.raises(ValueError, match=r"observation of shape \[N, 3\], got \(200, 4\)"):
        Normalizer(3, 2).fit(torch.randn(200, 4), act)
