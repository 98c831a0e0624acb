"""Tests of ``OneStepFastPath`` (``torchrl_dual/diffusion/_fast_path/one_step_fast_path.py``):
which transition planners pair with the policy query, and that the shortcut equals the
general path for the planner itself (one stacked pass) and for a frozen copy (paired trunks)."""

from __future__ import annotations

import pytest
import torch
from toy import assert_all_close, fine_tuned, plain_features, plain_prediction, transition_inputs

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.diffusion._fast_path import OneStepFastPath


def _fast_path(model) -> OneStepFastPath:
    layout = model.layout
    sigma_1 = float(model.schedule(torch.ones(()))[1])
    return OneStepFastPath(model, sigma_1, slice(layout.transition_dim, layout.transition_dim + 3))


def _count_trunk_calls(monkeypatch, model) -> list:
    calls = []
    original = model.denoiser.trunk
    monkeypatch.setattr(
        model.denoiser, "trunk", lambda hidden: calls.append(hidden.shape) or original(hidden)
    )
    return calls


# ----------------------------------------------------------------------------- pairs_with
def test_the_planner_itself_and_a_same_shape_one_step_copy_pair(make_model):
    model = make_model(num_steps=1)
    fast = _fast_path(model)
    assert fast.pairs_with(model)
    assert fast.pairs_with(fine_tuned(model))
    assert fast.pairs_with(make_model(num_steps=1, seed=5))  # other weights, same shape


@pytest.mark.parametrize(
    "other",
    [
        dict(num_steps=2),
        dict(layout=TrajectoryLayout(3, 2, 6)),
        dict(layout=TrajectoryLayout(4, 2, 4)),
        dict(hidden=16),
        dict(depth=2),
        dict(schedule="linear"),  # σ_1 = 0.99998 instead of 1
    ],
    ids=["multi-step", "horizon", "obs-dim", "width", "depth", "schedule"],
)
def test_planners_of_another_shape_or_schedule_do_not_pair(make_model, other):
    fast = _fast_path(make_model(num_steps=1))
    kwargs = dict(layout=TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1) | other
    assert not fast.pairs_with(TrajectoryDiffusion(kwargs.pop("layout"), **kwargs))


# ----------------------------------------------------------------------------- exactness
@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_features_equal_the_plain_path(make_model, batch):
    model = make_model(num_steps=1)
    observation = transition_inputs(*batch)[0]
    with torch.no_grad():
        fast = _fast_path(model).features(observation)
        plain = plain_features(model, observation)
    assert fast.shape == (*batch, 32)
    torch.testing.assert_close(fast, plain, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
@pytest.mark.parametrize("transition", ["shared", "frozen-copy"])
def test_features_with_transition_equal_the_plain_path(make_model, monkeypatch, batch, transition):
    model = make_model(num_steps=1)
    planner = model if transition == "shared" else fine_tuned(model).requires_grad_(False)
    observation, previous_observation, previous_action = transition_inputs(*batch)
    calls = [
        _count_trunk_calls(monkeypatch, m) for m in {id(m): m for m in (model, planner)}.values()
    ]
    with torch.no_grad():
        fast = _fast_path(model).features_with_transition(
            observation, planner, previous_observation, previous_action
        )
    # one pass: the stacked trunk of the planner itself, or the paired trunks (no trunk call)
    assert [len(c) for c in calls] == ([1] if transition == "shared" else [0, 0])
    with torch.no_grad():
        plain = (
            plain_features(model, observation),
            plain_prediction(planner, previous_observation, previous_action),
        )
    assert fast[1].shape == observation.shape
    assert_all_close(fast, plain)
    if transition == "frozen-copy":  # the copy's own weights, not the policy planner's
        own = plain_prediction(model, previous_observation, previous_action)
        assert not torch.allclose(fast[1], own, atol=1e-3)


def test_a_new_transition_planner_is_paired_anew(make_model):
    model = make_model(num_steps=1)
    fast = _fast_path(model)
    inputs = transition_inputs(4)
    first, second = fine_tuned(model, seed=1), fine_tuned(model, seed=2)
    with torch.no_grad():
        fast.features_with_transition(inputs[0], first, *inputs[1:])
        predicted = fast.features_with_transition(inputs[0], second, *inputs[1:])[1]
        again = fast.features_with_transition(inputs[0], first, *inputs[1:])[1]
    torch.testing.assert_close(predicted, plain_prediction(second, *inputs[1:]))
    torch.testing.assert_close(again, plain_prediction(first, *inputs[1:]))
