"""The executed action of DUAL's unbounded Gaussian policy (``modules/actors/action_box.py``)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded, OneHot, Unbounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules.distributions.utils import rsample_and_log_prob

from torchrl_dual.modules.actors.action_box import ActionBox, ClippedNormal, box_bounds
from torchrl_dual.recipe.parts.critics import policy_view

LOW, HIGH = torch.tensor([-1.0, 0.0]), torch.tensor([1.0, 2.0])


def test_clipped_normal_draws_stay_in_the_box_and_score_the_censored_gaussian():
    loc = torch.tensor([[0.9, 2.5], [-3.0, 1.0]], requires_grad=True)
    scale = torch.full((2, 2), 0.5)
    dist = ClippedNormal(loc, scale, low=LOW, high=HIGH)
    torch.manual_seed(0)
    action, log_prob = rsample_and_log_prob(dist)  # what TorchRL's losses call
    torch.manual_seed(0)
    normal = torch.distributions.Normal(loc, scale)
    draw = normal.rsample()
    torch.testing.assert_close(action, torch.clamp(draw, LOW, HIGH))
    # by hand: the density inside, the mass beyond each face on it
    low_mass = normal.cdf(LOW.expand_as(loc)).log()
    high_mass = (1 - normal.cdf(HIGH.expand_as(loc))).log()
    by_hand = torch.where(
        draw >= HIGH, high_mass, torch.where(draw <= LOW, low_mass, normal.log_prob(draw))
    )
    torch.testing.assert_close(log_prob, by_hand.sum(-1))
    # the pathwise gradient is the identity inside the box and zero on a clamped entry
    (grad,) = torch.autograd.grad(action.sum(), loc, retain_graph=True)
    inside = ((draw > LOW) & (draw < HIGH)).float()
    torch.testing.assert_close(grad, inside)
    assert 0 < inside.sum() < inside.numel()  # both cases exercised
    samples = dist.sample((2000,))
    assert bool((samples >= LOW).all() and (samples <= HIGH).all())
    assert (samples == HIGH).float().mean() > 0.2  # mass piles on the faces it crosses
    torch.testing.assert_close(dist.deterministic_sample, torch.clamp(loc, LOW, HIGH))
    torch.testing.assert_close(dist.mode, torch.clamp(loc, LOW, HIGH))


def test_clipped_normal_scores_sum_to_one_over_the_box():
    """The censored distribution is normalised: the density integrated over the interior
    plus the two face masses is 1 (one dimension, trapezoid rule)."""
    dist = ClippedNormal(torch.tensor([0.7]), torch.tensor([0.4]), low=-1.0, high=1.0)
    grid = torch.linspace(-1, 1, 20001)[1:-1, None]
    interior = torch.trapezoid(dist.log_prob(grid).exp(), grid[:, 0])
    faces = dist.log_prob(torch.tensor([[-1.0], [1.0]])).exp().sum()
    torch.testing.assert_close(interior + faces, torch.tensor(1.0), atol=1e-3, rtol=0)


def test_action_box_clamps_with_the_spec_and_passes_unbounded_actions_through():
    action = torch.tensor([[3.0, -1.0], [-0.5, 0.5]])
    torch.testing.assert_close(
        ActionBox(Bounded(LOW, HIGH, shape=(2,)))(action), torch.tensor([[1.0, 0.0], [-0.5, 0.5]])
    )
    torch.testing.assert_close(ActionBox(Unbounded(shape=(2,)))(action), action)
    with pytest.raises(TypeError, match="Bounded or Unbounded action spec, got OneHot"):
        box_bounds(OneHot(4))


class _FarMean(nn.Module):
    """A last-layer actor stand-in whose mean lies far outside the box."""

    def __init__(self) -> None:
        super().__init__()
        self.log_std = nn.Parameter(torch.zeros(2))
        self.std = torch.ones(2)

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return torch.full((*observation.shape[:-1], 2), 5.0)


def test_policy_view_gives_critics_the_executed_action():
    """Cal-QL's penalty and targets and SO2's targets draw DUAL's policy through this view
    (``get_dist`` and the module call): never an action outside the env's box."""
    view = policy_view(_FarMean(), Bounded(LOW, HIGH, shape=(2,)))
    td = TensorDict({"observation": torch.randn(64, 3)}, [64])
    action, _ = rsample_and_log_prob(view.get_dist(td))
    assert bool((action <= HIGH).all() and (action >= LOW).all())
    for mode in (ExplorationType.RANDOM, ExplorationType.DETERMINISTIC):
        with set_exploration_type(mode):
            out = view(td.clone())
        assert bool((out["action"] <= HIGH).all() and (out["action"] >= LOW).all())
        assert out["action_log_prob"].shape == (64,)


def test_action_box_distribution_is_the_clipped_normal_on_the_spec_box():
    box = ActionBox(Bounded(LOW, HIGH, shape=(2,)))
    loc, scale = torch.tensor([0.5, 3.0]), torch.tensor([0.5, 2.0])
    dist = box.distribution(loc, scale)
    assert isinstance(dist, ClippedNormal)
    torch.testing.assert_close(dist.mean, loc)
    torch.testing.assert_close(dist.stddev, scale)
    torch.testing.assert_close(dist.deterministic_sample, torch.tensor([0.5, 2.0]))
    # by hand: the density at 0 in dimension 0, the mass below the face 0 in dimension 1
    normal = torch.distributions.Normal(loc, scale)
    expected = normal.log_prob(torch.tensor(0.0))[0] + normal.cdf(torch.tensor(0.0))[1].log()
    torch.testing.assert_close(dist.log_prob(torch.tensor([0.0, 0.0])), expected)
    far = box.distribution(torch.tensor([-5.0, -5.0]), torch.ones(2))
    torch.testing.assert_close(far.deterministic_sample, LOW)


def test_clipped_normal_defaults_to_the_unit_box():
    dist = ClippedNormal(torch.tensor([3.0, -3.0, 0.25]), torch.ones(3))
    torch.testing.assert_close(dist.deterministic_sample, torch.tensor([1.0, -1.0, 0.25]))
    # the face at +1 carries P(X ≥ 1) = Φ(-2) in dimension 0
    value = torch.tensor([1.0, -1.0, 0.25])
    normal = torch.distributions.Normal(dist.mean, torch.ones(3))
    expected = (
        (1 - normal.cdf(torch.tensor(1.0))[0]).log()
        + normal.cdf(torch.tensor(-1.0))[1].log()
        + normal.log_prob(value)[2]
    )
    torch.testing.assert_close(dist.log_prob(value), expected)


def test_clipped_normal_passes_its_options_to_the_independent_normal():
    loc = torch.zeros(4, 3, 2)
    assert ClippedNormal(loc, torch.ones(4, 3, 2)).event_shape == (2,)  # IndependentNormal's
    dist = ClippedNormal(loc, torch.ones(4, 3, 2), event_dim=2)
    assert dist.event_shape == (3, 2) and dist.batch_shape == (4,)


def test_clipped_normal_box_takes_the_dtype_and_device_of_loc():
    dist = ClippedNormal(
        torch.tensor([5.0, -5.0], dtype=torch.float64),
        torch.ones(2, dtype=torch.float64),
        low=-1 / 3,
        high=1 / 3,
    )
    assert dist.low.dtype == dist.high.dtype == torch.float64
    # the clamp lands exactly on the float64 faces (a float32 box would round them)
    assert torch.equal(
        dist.deterministic_sample, torch.tensor([1 / 3, -1 / 3], dtype=torch.float64)
    )
    meta = ClippedNormal(torch.zeros(2, device="meta"), torch.ones(2, device="meta"))
    assert meta.low.device.type == meta.high.device.type == "meta"


def test_clipped_normal_log_prob_sums_over_the_last_dimension_only():
    loc = torch.zeros(4, 3, 2)
    dist = ClippedNormal(loc, torch.ones(4, 3, 2), low=-1.0, high=1.0)
    value = torch.tensor([0.5, 1.0]).expand(4, 3, 2)
    log_prob = dist.log_prob(value)
    assert log_prob.shape == (4, 3)
    normal = torch.distributions.Normal(0.0, 1.0)
    expected = normal.log_prob(torch.tensor(0.5)) + (1 - normal.cdf(torch.tensor(1.0))).log()
    torch.testing.assert_close(log_prob, expected.expand(4, 3))
