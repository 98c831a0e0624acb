"""Tests of ``OneStepFold`` (``torchrl_dual/diffusion/_fast_path/one_step_fold.py``): the folded
first layer and read-out of the one-step planner equal the general path, and follow every
change of the tensors they are derived from."""

from __future__ import annotations

import copy

import pytest
import torch
from torch.nn import functional as F  # noqa: N812
from toy import (
    WEIGHT_CHANGES,
    apply_weight_change,
    assert_all_close,
    plain_features,
    plain_prediction,
    transition_inputs,
)

from torchrl_dual.diffusion._fast_path.one_step_fold import OneStepFold


def _model(make_model, seed: int = 0):
    model = make_model(num_steps=1, seed=seed)
    gen = torch.Generator().manual_seed(seed)
    model.normalizer.fit(  # per-dimension mean and scale, so the folding of (μ, σ) matters
        torch.randn(256, 3, generator=gen) * torch.tensor([0.5, 2.0, 4.0]) + 3.0,
        torch.randn(256, 2, generator=gen) * 0.3 - 0.2,
    )
    return model


def _fold(model) -> OneStepFold:
    layout = model.layout
    sigma_1 = float(model.schedule(torch.ones(()))[1])
    rows = slice(layout.transition_dim, layout.transition_dim + layout.obs_dim)
    return OneStepFold(model, sigma_1, rows)


def _folded(fold, model, observation, previous_observation, previous_action):
    """``(φ(s_t), φ(s_{t-1}, a_{t-1}), ŝ_t)`` computed from the folded tensors alone."""
    w_state, w_action, const, w_next, b_next = fold.tensors()
    trunk = model.denoiser.trunk
    policy = trunk(F.linear(observation, w_state, const[0]))
    query = F.linear(previous_observation, w_state, const[1]) + F.linear(previous_action, w_action)
    transition = trunk(query)
    return policy, transition, F.linear(transition, w_next, b_next)


def _general(model, observation, previous_observation, previous_action):
    return (
        plain_features(model, observation),
        plain_features(model, previous_observation, previous_action),
        plain_prediction(model, previous_observation, previous_action),
    )


@pytest.mark.parametrize("batch", [(), (7,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_folded_queries_equal_the_general_path(make_model, batch):
    model = _model(make_model)
    inputs = transition_inputs(*batch)
    with torch.no_grad():
        folded = _folded(_fold(model), model, *inputs)
        general = _general(model, *inputs)
    assert folded[0].shape == (*batch, model.denoiser.feature_dim)
    assert folded[2].shape == (*batch, 3)
    assert_all_close(folded, general)


def test_folded_tensors_have_the_documented_shapes(make_model):
    w_state, w_action, const, w_next, b_next = _fold(_model(make_model)).tensors()
    hidden = 32
    assert (w_state.shape, w_action.shape, const.shape) == ((hidden, 3), (hidden, 2), (2, hidden))
    assert (w_next.shape, b_next.shape) == ((3, hidden), (3,))


def test_folded_tensors_are_reused_until_a_source_tensor_changes(make_model):
    model = _model(make_model)
    fold = _fold(model)
    first = fold.tensors()
    assert fold.tensors() is first  # cache hit: nothing was recomputed
    with torch.no_grad():
        model.denoiser.blocks[0].net[1].weight.add_(1.0)  # not an input of the fold
    assert fold.tensors() is first
    with torch.no_grad():
        model.denoiser.input_layer.bias.add_(1.0)
    assert fold.tensors() is not first
    second = fold.tensors()
    model.normalizer.obs_mean.add_(1.0)  # the normalizer is a source too
    assert fold.tensors() is not second


@pytest.mark.parametrize("change", WEIGHT_CHANGES)
def test_folded_queries_follow_every_kind_of_weight_change(make_model, change):
    model = _model(make_model)
    fold = _fold(model)
    inputs = transition_inputs(5)
    with torch.no_grad():
        before = _folded(fold, model, *inputs)
    apply_weight_change(model, change)
    dtype = model.denoiser.head.weight.dtype
    inputs = tuple(x.to(dtype) for x in inputs)
    with torch.no_grad():
        folded = _folded(fold, model, *inputs)
        general = _general(model, *inputs)
    assert folded[2].dtype == dtype
    if change != "double":  # the change matters: a stale cache would be caught
        assert not torch.allclose(folded[2], before[2], atol=1e-4)
    assert_all_close(folded, general)


def test_a_deep_copy_folds_its_own_weights(make_model):
    model = _model(make_model)
    fold = _fold(model)
    inputs = transition_inputs(4)
    observation = inputs[0]
    with torch.no_grad():
        fold.tensors()  # filled before the copy
        twin, twin_fold = copy.deepcopy((model, fold))  # one memo: the copy folds the copy
        twin.denoiser.input_layer.weight.mul_(-1.0)
        mine = _folded(fold, model, *inputs)[0]
        theirs = _folded(twin_fold, twin, *inputs)[0]
        assert not torch.allclose(mine, theirs)
        torch.testing.assert_close(theirs, plain_features(twin, observation), rtol=1e-5, atol=1e-5)
        torch.testing.assert_close(mine, plain_features(model, observation), rtol=1e-5, atol=1e-5)
