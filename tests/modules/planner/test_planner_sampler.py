"""Tests of ``PlannerSampler`` (``torchrl_dual/modules/planner/planner_sampler.py``): the planner
sampled given ``s_0`` (and ``a_0``), in raw units (Eq. 5 and the transition model)."""

from __future__ import annotations

import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules import PlannerSampler

pytestmark = pytest.mark.usefixtures("seeded")


def _observation(model, batch=5):
    return torch.randn(batch, model.layout.obs_dim) * 3.0 + 1.0


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
@pytest.mark.parametrize("num_steps", [1, 2, 32])
def test_plan_returns_the_raw_observation_in_row_zero_exactly(sampler, num_steps, make_model):
    model = make_model(num_steps=32)
    observation = _observation(model)
    window = PlannerSampler(model, num_steps=num_steps, sampler=sampler).plan(observation)
    assert window.shape == (5, *model.layout.window_shape)
    assert torch.equal(model.layout.observations(window)[:, 0], observation)


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_plan_with_an_action_returns_the_raw_action_in_row_zero_exactly(sampler, make_model):
    model = make_model(num_steps=4)
    observation = _observation(model)
    action = torch.rand(5, model.layout.action_dim) * 2 - 1
    window = PlannerSampler(model, sampler=sampler).plan(observation, action)
    assert torch.equal(model.layout.observations(window)[:, 0], observation)
    assert torch.equal(model.layout.actions(window)[:, 0], action)


def test_plan_does_not_modify_its_input(make_model):
    model = make_model(num_steps=2)
    observation = _observation(model)
    before = observation.clone()
    PlannerSampler(model).plan(observation)
    assert torch.equal(observation, before)


def test_plan_rejects_a_wrong_observation_dim_and_nan(make_model):
    sampler = PlannerSampler(make_model(num_steps=1))
    with pytest.raises(ValueError, match=r"end with dim 3 .*got shape \(5, 4\)"):
        sampler.plan(torch.randn(5, 4))
    with pytest.raises(ValueError, match="NaN"):
        sampler.plan(torch.full((5, 3), float("nan")))


def test_a_step_count_that_does_not_divide_n_is_rejected_at_construction(make_model):
    with pytest.raises(ValueError, match="divisor"):
        PlannerSampler(make_model(num_steps=32), num_steps=3)


def test_forward_returns_the_first_action_and_second_state_of_the_plan(make_model):
    model = make_model(num_steps=2)
    observation = _observation(model)
    sampler = PlannerSampler(model)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        window = sampler.plan(observation)
        action, next_observation = sampler(observation)
    assert torch.equal(action, model.layout.actions(window)[:, 0])
    assert torch.equal(next_observation, model.layout.observations(window)[:, 1])


def test_deterministic_plans_are_the_ddim_image_of_the_zero_latent(make_model):
    model = make_model(num_steps=4)
    observation = _observation(model)
    norm = model.normalizer
    cond, mask = model.layout.conditioned_window(norm.normalize_observation(observation))
    expected = model.sample(cond, mask, sampler="ddim", noise=torch.zeros_like(cond))
    for sampler in ("ddim", "ddpm"):  # whatever the configured sampler
        window = PlannerSampler(model, sampler=sampler).normalized_window(
            observation, deterministic=True
        )
        assert torch.equal(window, expected), sampler
    with set_exploration_type(ExplorationType.DETERMINISTIC):  # the mode decides by default
        assert torch.equal(PlannerSampler(model).normalized_window(observation), expected)


def test_predict_next_observation_is_row_one_of_the_action_conditioned_plan(make_model):
    model = make_model(num_steps=2)
    observation, action = _observation(model), torch.rand(5, model.layout.action_dim)
    sampler = PlannerSampler(model)
    predicted = sampler.predict_next_observation(observation, action, deterministic=True)
    window = sampler.plan(observation, action, deterministic=True)
    assert predicted.shape == observation.shape
    assert torch.equal(predicted, model.layout.observations(window)[:, 1])
    drawn = sampler.predict_next_observation(observation, action, deterministic=False)
    assert not torch.allclose(drawn, predicted)
