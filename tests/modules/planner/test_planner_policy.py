"""Tests of ``PlannerPolicy`` (``torchrl_dual/modules/planner/planner_policy.py``): the planner
as a TorchRL policy, ``a = τ_{a_0}`` with ``τ ~ p_θ(τ | τ_{s_0} = s)`` (Eq. 5)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.diffusion import NoiseSchedule
from torchrl_dual.modules import PlannerPolicy

pytestmark = pytest.mark.usefixtures("seeded")

MODES = {"deterministic": ExplorationType.DETERMINISTIC, "random": ExplorationType.RANDOM}


def _observation(model, batch=5):
    return torch.randn(batch, model.layout.obs_dim) * 3.0 + 1.0


def _td(observation):
    return TensorDict({"observation": observation}, batch_size=observation.shape[:-1])


# ----------------------------------------------------------------------------- values
@pytest.mark.parametrize("mode", MODES)
def test_the_one_step_action_is_the_ddim_closed_form(make_model, fixed_output_denoiser, mode):
    """``τ = α_1·z − σ_1·v̂`` with ``z`` the latent (zero when deterministic), de-normalised."""
    denoiser = fixed_output_denoiser()
    model = make_model(num_steps=1, denoiser=denoiser)
    model.schedule = NoiseSchedule("linear")  # α_1 = 0.0066 > 0: the latent shows in τ
    alpha, sigma = model.schedule(torch.ones(()))
    layout, norm = model.layout, model.normalizer
    observation = _observation(model)
    denoiser.value = torch.randn(5, *layout.window_shape)
    torch.manual_seed(3)
    latent = torch.randn(5, *layout.window_shape) if mode == "random" else torch.zeros(1)
    torch.manual_seed(3)
    with set_exploration_type(MODES[mode]):
        out = PlannerPolicy(model)(_td(observation))
    window = alpha * latent - sigma * denoiser.value
    expected_action = norm.denormalize_action(window[:, 0, layout.obs_dim :])
    expected_next = norm.denormalize_observation(window[:, 1, : layout.obs_dim])
    torch.testing.assert_close(out["action"], expected_action)
    torch.testing.assert_close(out["planned_next_observation"], expected_next)


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_a_point_mass_planner_plans_the_point_in_raw_units(make_model, point_mass_oracle, sampler):
    model = make_model(num_steps=4)
    layout, norm = model.layout, model.normalizer
    c = torch.linspace(-1.5, 1.5, layout.length * layout.transition_dim).view(layout.window_shape)
    model.denoiser = point_mass_oracle(c, model.schedule)
    with set_exploration_type(ExplorationType.RANDOM):
        out = PlannerPolicy(model, sampler=sampler)(_td(_observation(model)))
    expected_action = norm.denormalize_action(c[0, layout.obs_dim :]).expand(5, -1)
    expected_next = norm.denormalize_observation(c[1, : layout.obs_dim]).expand(5, -1)
    torch.testing.assert_close(out["action"], expected_action, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(out["planned_next_observation"], expected_next, rtol=1e-4, atol=1e-4)


def test_known_entries_are_kept_exactly_whatever_the_denoiser_predicts(
    make_model, fixed_output_denoiser
):
    denoiser = fixed_output_denoiser()
    model = make_model(num_steps=1, denoiser=denoiser)
    denoiser.value = torch.full((5, *model.layout.window_shape), 1e3)  # far from any input
    observation = _observation(model)
    action = torch.rand(5, 2) * 2 - 1
    window = PlannerPolicy(model).module.plan(observation, action)
    assert torch.equal(model.layout.observations(window)[:, 0], observation)
    assert torch.equal(model.layout.actions(window)[:, 0], action)
    assert (model.layout.actions(window)[:, 1:].abs() > 10).all()  # the rest is the network's


# ----------------------------------------------------------------------------- modes
@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_deterministic_exploration_gives_the_same_plan_twice(sampler, make_model):
    policy = PlannerPolicy(make_model(num_steps=4), sampler=sampler)
    td = _td(_observation(policy.module.model))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        first, second = policy(td.clone()), policy(td.clone())
    assert torch.equal(first["action"], second["action"])
    assert torch.equal(first["planned_next_observation"], second["planned_next_observation"])


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_random_exploration_gives_different_plans(sampler, make_model):
    policy = PlannerPolicy(make_model(num_steps=4), sampler=sampler)
    td = _td(_observation(policy.module.model))
    with set_exploration_type(ExplorationType.RANDOM):
        first, second = policy(td.clone()), policy(td.clone())
    assert not torch.equal(first["action"], second["action"])


# ----------------------------------------------------------------------------- interface
def test_the_action_and_planned_next_observation_have_the_right_shape(make_model):
    model = make_model(num_steps=1)
    out = PlannerPolicy(model)(_td(_observation(model, batch=7)))
    assert out["action"].shape == (7, model.layout.action_dim)
    assert out["planned_next_observation"].shape == (7, model.layout.obs_dim)


@pytest.mark.parametrize("num_steps", [1, 4])
def test_an_unbatched_observation_as_an_env_step_gives_is_accepted(num_steps, make_model):
    model = make_model(num_steps=4)
    observation = _observation(model, batch=1)[0]
    out = PlannerPolicy(model, num_steps=num_steps)(TensorDict({"observation": observation}, []))
    assert out["action"].shape == (model.layout.action_dim,)
    assert out["planned_next_observation"].shape == (model.layout.obs_dim,)


def test_the_action_is_clamped_to_the_given_bounds(make_model):
    model = make_model(num_steps=1)
    # a huge action scale makes unclamped actions leave [-0.1, 0.1] almost surely
    model.normalizer.action_std.fill_(100.0)
    td = _td(_observation(model, batch=64))
    with set_exploration_type(ExplorationType.RANDOM):
        raw = PlannerPolicy(model)(td.clone())["action"]
        clamped = PlannerPolicy(model, action_low=-0.1, action_high=0.1)(td.clone())["action"]
    assert raw.abs().max() > 0.1
    assert clamped.min() >= -0.1 and clamped.max() <= 0.1
    low, high = torch.tensor([-0.1, -0.2]), torch.tensor([0.1, 0.2])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        unclamped = PlannerPolicy(model)(td.clone())["action"]
        per_dim = PlannerPolicy(model, action_low=low, action_high=high)(td.clone())["action"]
    assert torch.equal(per_dim, unclamped.clamp(low, high))


def test_custom_keys_are_read_and_written(make_model):
    model = make_model(num_steps=1)
    policy = PlannerPolicy(
        model,
        observation_key=("agent", "obs"),
        action_key=("agent", "act"),
        next_observation_key="s1_hat",
    )
    assert policy.in_keys == [("agent", "obs")]
    assert policy.out_keys == [("agent", "act"), "s1_hat"]
    out = policy(TensorDict({"agent": {"obs": _observation(model)}}, batch_size=[5]))
    assert out["agent", "act"].shape == (5, 2)
    assert out["s1_hat"].shape == (5, 3)
    assert "action" not in out.keys()


def test_a_missing_observation_names_the_reader_and_the_keys_present(make_model):
    policy = PlannerPolicy(make_model(num_steps=1))
    with pytest.raises(KeyError, match=r"The planner reads 'observation'.*holds \['obs'\]"):
        policy(TensorDict({"obs": torch.zeros(2, 3)}, batch_size=[2]))


def test_a_step_count_that_does_not_divide_n_is_rejected_at_construction(make_model):
    with pytest.raises(ValueError, match="divisor"):
        PlannerPolicy(make_model(num_steps=32), num_steps=3)
