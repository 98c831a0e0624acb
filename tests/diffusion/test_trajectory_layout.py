"""Tests of ``TrajectoryLayout`` (``torchrl_dual/diffusion/trajectory_layout.py``): the window
``τ = (s_0, a_0, …, s_H, a_H)`` as a ``[H + 1, obs_dim + action_dim]`` tensor and its masks."""

from __future__ import annotations

import pytest
import torch

from torchrl_dual.diffusion import CONDITIONS, TrajectoryLayout


def test_shapes_follow_the_dimensions_and_the_horizon():
    layout = TrajectoryLayout(obs_dim=4, action_dim=2, horizon=8)
    assert (layout.length, layout.transition_dim, layout.window_shape) == (9, 6, (9, 6))
    assert TrajectoryLayout(3, 1).horizon == 8  # the paper's default H


def test_pack_observations_and_actions_are_inverse_views():
    layout = TrajectoryLayout(3, 2, 4)
    observation, action = torch.randn(7, 5, 3), torch.randn(7, 5, 2)
    window = layout.pack(observation, action)
    assert window.shape == (7, 5, 5)
    assert torch.equal(layout.observations(window), observation)
    assert torch.equal(layout.actions(window), action)


@pytest.mark.parametrize("condition, known", [("s0", 3), ("s0_a0", 5)])
def test_condition_masks_mark_row_zero_only(condition, known):
    layout = TrajectoryLayout(3, 2, 4)
    mask = layout.condition_mask(condition)
    assert mask.dtype == torch.bool and mask.shape == (5, 5)
    assert mask[0].sum() == known and mask[0, :known].all()
    assert not mask[1:].any()


def test_an_unknown_condition_lists_the_options():
    with pytest.raises(ValueError) as err:
        TrajectoryLayout(3, 2, 4).condition_mask("a0")
    assert str(err.value) == f"Unknown condition 'a0'; choose one of {CONDITIONS}."


@pytest.mark.parametrize("with_action", [False, True])
def test_conditioned_window_holds_the_known_row_and_zeros_elsewhere(with_action):
    layout = TrajectoryLayout(3, 2, 4)
    observation = torch.randn(2, 6, 3)
    action = torch.randn(2, 6, 2) if with_action else None
    window, mask = layout.conditioned_window(observation, action)
    assert window.shape == mask.shape == (2, 6, 5, 5)
    assert torch.equal(window[..., 0, :3], observation)
    if with_action:
        assert torch.equal(window[..., 0, 3:], action)
    assert torch.equal(mask[0, 0], layout.condition_mask("s0_a0" if with_action else "s0"))
    assert not window[mask.logical_not()].any()  # every unknown entry is zero


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(obs_dim=0, action_dim=2), "obs_dim must be >= 1, got 0"),
        (dict(obs_dim=3, action_dim=0), "action_dim must be >= 1, got 0"),
        (
            dict(obs_dim=3, action_dim=2, horizon=0),
            r"horizon must be >= 1 \(the window needs s_1\)",
        ),
    ],
)
def test_bad_dimensions_are_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TrajectoryLayout(**kwargs)


def test_layouts_are_frozen_values():
    assert TrajectoryLayout(3, 2, 4) == TrajectoryLayout(3, 2, 4)
    assert TrajectoryLayout(3, 2, 4) != TrajectoryLayout(3, 2, 5)
    with pytest.raises(AttributeError):
        TrajectoryLayout(3, 2, 4).horizon = 6
