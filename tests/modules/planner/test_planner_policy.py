"""Tests of ``PlannerSampler``, ``PlannerPolicy`` and ``TransitionModel``
(``torchrl_dual/modules/planner_policy.py``, Eq. 5 and Algorithm 1 line 5)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.modules.planner.planner_policy import PlannerPolicy, PlannerSampler, TransitionModel

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
    model = make_model(num_steps=1)
    sampler = PlannerSampler(model)
    with pytest.raises(ValueError, match=r"end with dim 3 .*got shape \(5, 4\)"):
        sampler.plan(torch.randn(5, 4))
    with pytest.raises(ValueError, match="NaN"):
        sampler.plan(torch.full((5, 3), float("nan")))


def test_policy_num_steps_that_does_not_divide_n_is_rejected_at_construction(make_model):
    with pytest.raises(ValueError, match="divisor"):
        PlannerPolicy(make_model(num_steps=32), num_steps=3)


def test_policy_is_deterministic_under_deterministic_exploration(make_model):
    policy = PlannerPolicy(make_model(num_steps=4))
    td = TensorDict({"observation": _observation(policy.module.model)}, batch_size=[5])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        first = policy(td.clone())
        second = policy(td.clone())
    assert torch.equal(first["action"], second["action"])
    assert torch.equal(first["planned_next_observation"], second["planned_next_observation"])


def test_ddpm_policy_is_deterministic_under_deterministic_exploration(make_model):
    policy = PlannerPolicy(make_model(num_steps=4), sampler="ddpm")
    td = TensorDict({"observation": _observation(policy.module.model)}, batch_size=[5])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        first, second = policy(td.clone()), policy(td.clone())
    assert torch.equal(first["action"], second["action"])


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_policy_is_stochastic_under_random_exploration(sampler, make_model):
    policy = PlannerPolicy(make_model(num_steps=4), sampler=sampler)
    td = TensorDict({"observation": _observation(policy.module.model)}, batch_size=[5])
    with set_exploration_type(ExplorationType.RANDOM):
        first, second = policy(td.clone()), policy(td.clone())
    assert not torch.equal(first["action"], second["action"])


def test_policy_writes_action_and_planned_next_observation_of_the_right_shape(make_model):
    model = make_model(num_steps=1)
    td = TensorDict({"observation": _observation(model, batch=7)}, batch_size=[7])
    out = PlannerPolicy(model)(td)
    assert out["action"].shape == (7, model.layout.action_dim)
    assert out["planned_next_observation"].shape == (7, model.layout.obs_dim)


def test_policy_output_is_the_first_action_and_second_state_of_the_plan(make_model):
    model = make_model(num_steps=2)
    observation = _observation(model)
    sampler = PlannerSampler(model)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        window = sampler.plan(observation)
        action, next_observation = sampler(observation)
    assert torch.equal(action, model.layout.actions(window)[:, 0])
    assert torch.equal(next_observation, model.layout.observations(window)[:, 1])


def test_policy_clamps_the_action_to_the_given_bounds(make_model):
    model = make_model(num_steps=1)
    # a huge action scale makes unclamped actions leave [-0.1, 0.1] almost surely
    model.normalizer.action_std.fill_(100.0)
    td = TensorDict({"observation": _observation(model, batch=64)}, batch_size=[64])
    with set_exploration_type(ExplorationType.RANDOM):
        raw = PlannerPolicy(model)(td.clone())["action"]
        clamped = PlannerPolicy(model, action_low=-0.1, action_high=0.1)(td.clone())["action"]
    assert raw.abs().max() > 0.1
    assert clamped.min() >= -0.1 and clamped.max() <= 0.1
    low, high = torch.tensor([-0.1, -0.2]), torch.tensor([0.1, 0.2])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        per_dim = PlannerPolicy(model, action_low=low, action_high=high)(td.clone())["action"]
    assert (per_dim >= low).all() and (per_dim <= high).all()


def test_policy_reads_and_writes_custom_keys(make_model):
    model = make_model(num_steps=1)
    policy = PlannerPolicy(
        model,
        observation_key=("agent", "obs"),
        action_key=("agent", "act"),
        next_observation_key="s1_hat",
    )
    td = TensorDict({"agent": {"obs": _observation(model)}}, batch_size=[5])
    out = policy(td)
    assert out["agent", "act"].shape == (5, 2)
    assert out["s1_hat"].shape == (5, 3)


def test_transition_model_writes_predicted_observation_of_the_right_shape(make_model):
    model = make_model(num_steps=2)
    observation = _observation(model, batch=6)
    action = torch.rand(6, model.layout.action_dim)
    td = TensorDict({"observation": observation, "action": action}, batch_size=[6])
    out = TransitionModel(model)(td)
    assert out["predicted_observation"].shape == (6, model.layout.obs_dim)
    assert torch.isfinite(out["predicted_observation"]).all()
    assert torch.equal(out["observation"], observation) and torch.equal(out["action"], action)


def test_transition_model_predicts_row_one_of_the_action_conditioned_plan(make_model):
    model = make_model(num_steps=2)
    observation, action = _observation(model), torch.rand(5, model.layout.action_dim)
    transition = TransitionModel(model)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        predicted = transition.predict(observation, action)
        window = PlannerSampler(model).plan(observation, action)
    assert torch.equal(predicted, model.layout.observations(window)[:, 1])


@pytest.mark.parametrize("num_steps", [1, 4])
def test_policy_accepts_an_unbatched_observation_as_an_env_step_gives(num_steps, make_model):
    model = make_model(num_steps=4)
    observation = _observation(model, batch=1)[0]
    out = PlannerPolicy(model, num_steps=num_steps)(TensorDict({"observation": observation}, []))
    assert out["action"].shape == (model.layout.action_dim,)
    assert out["planned_next_observation"].shape == (model.layout.obs_dim,)


def test_transition_model_predicts_the_zero_latent_mean_even_while_exploring(make_model):
    model = make_model(num_steps=1)
    observation = _observation(model)
    action = torch.rand(observation.shape[0], model.layout.action_dim)
    with set_exploration_type(ExplorationType.RANDOM):
        first = TransitionModel(model).predict(observation, action)
        second = TransitionModel(model).predict(observation, action)
        sampled = TransitionModel(model, latent="sample")
        draws = sampled.predict(observation, action), sampled.predict(observation, action)
    torch.testing.assert_close(first, second)
    assert not torch.allclose(*draws)
    with pytest.raises(ValueError, match="latent"):
        TransitionModel(model, latent="mean")
