"""Tests of ``TrajectoryDiffusion`` (``torchrl_dual/diffusion/model.py``): forward process,
``v``-prediction algebra, DDIM/DDPM samplers, inpainting and checkpointing."""

from __future__ import annotations

import io

import pytest
import torch

from torchrl_dual.diffusion import SAMPLERS, SCHEDULES, NoiseSchedule, TrajectoryDiffusion

pytestmark = pytest.mark.usefixtures("seeded")

F64 = torch.float64
TIMES = (0.0, 0.1, 0.5, 0.9, 1.0)


@pytest.mark.parametrize("schedule", SCHEDULES)
def test_predict_with_the_true_v_recovers_x0_and_eps_exactly(
    schedule, make_layout, fixed_output_denoiser
):
    layout = make_layout()
    oracle = fixed_output_denoiser()
    model = TrajectoryDiffusion(layout, oracle, schedule=schedule)
    t = torch.tensor(TIMES, dtype=F64)
    x0 = torch.randn(len(TIMES), *layout.window_shape, dtype=F64)
    eps = torch.randn_like(x0)
    z = model.noise(x0, t, eps)
    oracle.value = model.v_target(x0, t, eps)
    no_mask = torch.zeros(layout.window_shape, dtype=torch.bool)

    x_hat, eps_hat, v_hat = model.predict(z, t, torch.zeros_like(x0), no_mask)

    torch.testing.assert_close(x_hat, x0, atol=1e-12, rtol=0)
    torch.testing.assert_close(eps_hat, eps, atol=1e-12, rtol=0)
    assert v_hat is oracle.value


def test_noising_at_t_zero_is_the_data_and_at_t_one_is_the_noise(make_layout):
    layout = make_layout()
    model = TrajectoryDiffusion(layout, hidden=32, depth=1)
    x0 = torch.randn(2, *layout.window_shape, dtype=F64)
    eps = torch.randn_like(x0)
    assert torch.equal(model.noise(x0, torch.zeros(2, dtype=F64), eps), x0)
    torch.testing.assert_close(model.noise(x0, torch.ones(2, dtype=F64), eps), eps)


def test_predict_keeps_the_known_entries_of_cond_exactly(make_model):
    model = make_model()
    layout = model.layout
    cond, mask = layout.conditioned_window(torch.randn(4, layout.obs_dim), torch.randn(4, 2))
    x_hat, _, _ = model.predict(torch.randn_like(cond), torch.rand(4), cond, mask)
    assert torch.equal(x_hat[mask], cond[mask])


@pytest.mark.parametrize("schedule", SCHEDULES)
@pytest.mark.parametrize("sampler", SAMPLERS)
@pytest.mark.parametrize("num_steps", [1, 32])
def test_sampler_with_a_point_mass_oracle_returns_the_point_exactly(
    schedule, sampler, num_steps, make_layout, point_mass_oracle
):
    layout = make_layout()
    c = torch.linspace(-2.0, 2.0, layout.length * layout.transition_dim, dtype=F64)
    c = c.reshape(layout.window_shape)
    oracle = point_mass_oracle(c, NoiseSchedule(schedule))
    model = TrajectoryDiffusion(layout, oracle, schedule=schedule, num_steps=32)
    cond = torch.zeros(6, *layout.window_shape, dtype=F64)
    no_mask = torch.zeros(layout.window_shape, dtype=torch.bool)

    out = model.sample(cond, no_mask, num_steps=num_steps, sampler=sampler)

    # exact up to float64 rounding of α·z − σ·v
    torch.testing.assert_close(out, c.expand_as(out), atol=1e-12, rtol=0)


@pytest.mark.parametrize("bad", [0, 3, 5, 64])
def test_time_grid_rejects_a_step_count_that_does_not_divide_n(bad, make_model):
    model = make_model(num_steps=32)
    with pytest.raises(ValueError, match=rf"num_steps={bad} must be a positive divisor .*N=32"):
        model.time_grid(bad)
    if bad:  # num_steps=0 must not silently mean N
        cond, mask = model.layout.conditioned_window(torch.zeros(1, model.layout.obs_dim))
        with pytest.raises(ValueError, match="divisor"):
            model.sample(cond, mask, num_steps=bad)


def test_sample_rejects_zero_steps(make_model):
    model = make_model(num_steps=4)
    cond, mask = model.layout.conditioned_window(torch.zeros(1, model.layout.obs_dim))
    with pytest.raises(ValueError, match="divisor"):
        model.sample(cond, mask, num_steps=0)


def test_time_grid_runs_from_one_to_zero_in_equal_steps(make_model):
    grid = make_model(num_steps=32).time_grid(8)
    torch.testing.assert_close(grid, torch.linspace(1.0, 0.0, 9))


def test_unknown_sampler_name_error_lists_the_options(make_model):
    model = make_model()
    cond, mask = model.layout.conditioned_window(torch.zeros(1, model.layout.obs_dim))
    with pytest.raises(ValueError, match="'ode'") as err:
        model.sample(cond, mask, sampler="ode")
    for name in SAMPLERS:
        assert name in str(err.value)


def test_sample_rejects_a_window_of_the_wrong_shape(make_model):
    model = make_model()
    with pytest.raises(ValueError, match=r"window shape \(5, 5\)"):
        model.sample(torch.zeros(2, 4, 5), torch.zeros(4, 5, dtype=torch.bool))


def test_num_steps_below_one_is_rejected(make_layout):
    with pytest.raises(ValueError, match="num_steps must be >= 1"):
        TrajectoryDiffusion(make_layout(), num_steps=0)


@pytest.mark.parametrize("sampler", SAMPLERS)
@pytest.mark.parametrize("num_steps", [1, 2, 32])
@pytest.mark.parametrize("with_action", [False, True])
def test_conditioning_keeps_s0_and_a0_exactly(sampler, num_steps, with_action, make_model):
    model = make_model(num_steps=32)
    layout = model.layout
    s0 = torch.randn(5, layout.obs_dim) * 3
    a0 = torch.randn(5, layout.action_dim) if with_action else None
    cond, mask = layout.conditioned_window(s0, a0)

    window = model.sample(cond, mask, num_steps=num_steps, sampler=sampler)

    assert window.shape == (5, *layout.window_shape)
    assert torch.equal(layout.observations(window)[:, 0], s0)
    if with_action:
        assert torch.equal(layout.actions(window)[:, 0], a0)
    assert torch.isfinite(window).all()


def test_ddim_is_deterministic_given_the_initial_noise(make_model):
    model = make_model(num_steps=4)
    cond, mask = model.layout.conditioned_window(torch.randn(3, model.layout.obs_dim))
    noise = torch.randn_like(cond)
    first = model.sample(cond, mask, noise=noise)
    assert torch.equal(first, model.sample(cond, mask, noise=noise))


def test_state_dict_round_trip_restores_weights_num_steps_and_normalizer(make_model):
    source = make_model(num_steps=1, seed=3)
    buffer = io.BytesIO()
    torch.save(source.state_dict(), buffer)
    buffer.seek(0)
    target = make_model(num_steps=32, fit=False, seed=4)

    target.load_state_dict(torch.load(buffer, weights_only=True))

    assert target.num_steps == 1
    assert bool(target.normalizer.fitted)
    for name, value in source.state_dict().items():
        assert torch.equal(target.state_dict()[name], value), name
    cond, mask = source.layout.conditioned_window(torch.randn(2, source.layout.obs_dim))
    noise = torch.randn_like(cond)
    assert torch.equal(
        source.sample(cond, mask, noise=noise), target.sample(cond, mask, noise=noise)
    )
    assert {"_num_steps", "normalizer.obs_mean", "normalizer.action_std"} <= set(
        source.state_dict()
    )


def test_normalized_window_standardises_each_dimension_with_the_fitted_data(make_layout):
    """``x_0`` as the planner is trained on it: every state and action dimension of the
    data it was fitted on has mean 0 and standard deviation 1 inside the window."""
    layout = make_layout()
    model = TrajectoryDiffusion(layout)
    scale_obs, scale_act = torch.arange(1.0, layout.obs_dim + 1), torch.tensor(0.1)
    observation = torch.randn(4096, layout.length, layout.obs_dim) * scale_obs + 3.0
    action = torch.randn(4096, layout.length, layout.action_dim) * scale_act - 1.0
    model.normalizer.fit(observation.flatten(0, 1), action.flatten(0, 1))

    x0 = model.normalized_window(observation, action)

    assert x0.shape == (4096, *layout.window_shape)
    flat = x0.flatten(0, 1)
    torch.testing.assert_close(flat.mean(0), torch.zeros(layout.transition_dim), atol=1e-5, rtol=0)
    torch.testing.assert_close(flat.std(0), torch.ones(layout.transition_dim), atol=1e-5, rtol=0)
    data = action.flatten(0, 1)
    torch.testing.assert_close(layout.actions(x0), (action - data.mean(0)) / data.std(0))
