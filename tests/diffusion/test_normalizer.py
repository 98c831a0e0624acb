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


NOT_FITTED = (
    r"^Normalizer is not fitted: call normalizer.fit\(observations, actions\) on the offline "
    r"data \(a planner's is model.normalizer\) or load a fitted state_dict first\.$"
)


@pytest.mark.parametrize(
    "method",
    ["normalize_observation", "denormalize_observation", "normalize_action", "denormalize_action"],
)
def test_an_unfitted_normalizer_refuses_to_normalise(method):
    """Its mean-0 / std-1 statistics would silently leave the data in raw units."""
    norm = Normalizer(3, 2)
    value = torch.zeros(4, 3 if "observation" in method else 2)
    with pytest.raises(RuntimeError, match=NOT_FITTED):
        getattr(norm, method)(value)
    obs, act = _data()
    norm.fit(obs, act)
    assert getattr(norm, method)(value).shape == value.shape


def test_loading_a_state_dict_carries_whether_it_was_fitted():
    obs, act = _data()
    fitted, unfitted = Normalizer(3, 2).fit(obs, act), Normalizer(3, 2)
    target = Normalizer(3, 2)
    target.load_state_dict(fitted.state_dict())
    torch.testing.assert_close(target.normalize_action(act), fitted.normalize_action(act))
    target.load_state_dict(unfitted.state_dict())
    with pytest.raises(RuntimeError, match=NOT_FITTED):
        target.normalize_action(act)


@pytest.mark.parametrize("grad", [False, True])  # the one-step shortcut, the plain path
def test_a_planner_whose_normalizer_was_never_fitted_is_refused_wherever_it_is_used(grad):
    from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
    from torchrl_dual.modules import PlannerActor, PlannerSampler

    model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=8, depth=1)
    with torch.set_grad_enabled(grad), pytest.raises(RuntimeError, match=NOT_FITTED):
        PlannerActor(model)(torch.zeros(4, 3))
    with pytest.raises(RuntimeError, match=NOT_FITTED):
        PlannerSampler(model)(torch.zeros(4, 3))
