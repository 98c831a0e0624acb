"""Tests of the ``LastLayerActor`` base class (``torchrl_dual/modules/actors/last_layer_actor.py``):
``μ(s) = readout((W φ(s) + b)[rows], context)``, the split Eq. 7-9 work on."""

from __future__ import annotations

import math

import pytest
import torch
from torch import nn
from torchrl.modules import MLP, TanhNormal
from toy import transition_inputs

from torchrl_dual.modules import LastLayerActor, LinearHeadActor, TransitionModel
from torchrl_dual.modules.actors.last_layer_actor import TanhSquash


class _Affine(LastLayerActor):
    """``μ(s) = 2 · (W s + b)[1:3] + s[..., :2]``: a read-out with a scale and a shift."""

    def __init__(self) -> None:
        super().__init__(2)
        self.head = nn.Linear(3, 4)
        self._set_head_rows(1, 3)

    def features(self, observation):
        return observation

    def readout(self, head_rows, context):
        return 2.0 * head_rows + context[..., :2]

    def readout_scale(self):
        return torch.full((2,), 2.0)


def test_the_mean_is_the_readout_of_the_selected_head_rows():
    actor = _Affine()
    observation = torch.randn(5, 3)
    expected = 2.0 * actor.head(observation)[:, 1:3] + observation[:, :2]
    torch.testing.assert_close(actor(observation), expected)
    weight, bias = actor.head_parameters()
    assert weight.data_ptr() == actor.head.weight[1].data_ptr()  # views of the head
    torch.testing.assert_close(actor.head_output(observation), actor.head(observation)[:, 1:3])
    assert actor.head_rows.tolist() == [1, 2] and "head_rows" in actor.state_dict()


def test_std_is_the_clamped_exp_of_log_std_and_saved_with_the_actor():
    actor = LinearHeadActor(
        MLP(in_features=3, out_features=2, num_cells=[8]), 2, min_std=0.1, max_std=1.0
    )
    torch.testing.assert_close(actor.std, torch.full((2,), 0.3))
    with torch.no_grad():
        actor.log_std.copy_(torch.tensor([-10.0, 10.0]))
    torch.testing.assert_close(actor.std, torch.tensor([0.1, 1.0]))
    assert actor.state_dict()["log_std"].tolist() == [-10.0, 10.0]
    assert math.isclose(actor.min_log_std, math.log(0.1))


def test_an_init_std_outside_the_bounds_is_rejected():
    with pytest.raises(
        ValueError, match=r"init_std=3.0 must lie in \[min_std=0.001, max_std=2.0\]"
    ):
        LastLayerActor(2, init_std=3.0)


def test_a_subclass_without_features_or_encode_says_what_to_override():
    class Bare(LastLayerActor):
        pass

    actor = Bare(2)
    with pytest.raises(NotImplementedError, match="Bare must override features\\(\\) or encode"):
        actor.features(torch.zeros(1, 3))
    with pytest.raises(NotImplementedError):
        actor.readout(torch.zeros(1, 2), torch.zeros(1, 3))


def test_encode_with_transition_is_encode_and_the_transition_prediction(make_model):
    actor = _Affine()
    transition = TransitionModel(make_model(num_steps=1))
    observation, previous_observation, previous_action = transition_inputs(4)
    features, context, predicted = actor.encode_with_transition(
        observation, transition, previous_observation, previous_action
    )
    torch.testing.assert_close(features, observation)
    assert context is observation
    torch.testing.assert_close(predicted, transition.predict(previous_observation, previous_action))


# ----------------------------------------------------------------------------- squash
def test_tanh_squash_maps_onto_the_box_like_tanh_normal():
    low, high = torch.tensor([0.0, -3.0]), torch.tensor([1.0, 1.0])
    squash = TanhSquash(low, high)
    u = torch.randn(100, 2) * 3
    torch.testing.assert_close(squash(u), low + (high - low) * (torch.tanh(u) + 1) / 2)
    mode = TanhNormal(u, torch.ones_like(u), low=low, high=high).deterministic_sample
    torch.testing.assert_close(squash(u), mode, atol=1e-5, rtol=0)  # up to SafeTanh's clamp
    with pytest.raises(ValueError, match="high > low"):
        TanhSquash(1.0, 1.0)


def test_act_is_the_readout_then_the_squash_and_forward_uses_it():
    actor = _Affine()
    observation = torch.randn(5, 3)
    head = actor.head_output(observation)
    assert actor.squash is None and "squash" not in dict(actor.named_children())
    torch.testing.assert_close(actor.act(head, observation), actor.readout(head, observation))
    actor.squash = TanhSquash(-2.0, 2.0)
    expected = 2.0 * torch.tanh(actor.readout(head, observation))
    torch.testing.assert_close(actor.act(head, observation), expected)
    torch.testing.assert_close(actor(observation), expected)
    torch.testing.assert_close(actor.readout_scale(), torch.full((2,), 2.0))  # pre-squash


def test_tanh_squash_defaults_to_the_unit_box():
    squash = TanhSquash()
    torch.testing.assert_close(squash.center, torch.tensor(0.0))
    torch.testing.assert_close(squash.half_range, torch.tensor(1.0))
    u = torch.tensor([-0.5, 0.0, 2.0])
    torch.testing.assert_close(squash(u), torch.tanh(u))


def test_tanh_squash_stores_its_box_in_the_default_dtype():
    squash = TanhSquash(
        torch.tensor([0.0, -1.0], dtype=torch.float64),
        torch.tensor([1.0, 3.0], dtype=torch.float64),
    )
    assert squash.center.dtype == squash.half_range.dtype == torch.get_default_dtype()
    torch.testing.assert_close(squash.center, torch.tensor([0.5, 1.0]))
    torch.testing.assert_close(squash.half_range, torch.tensor([0.5, 2.0]))


def test_tanh_squash_derivative_is_half_range_times_one_minus_tanh_squared():
    squash = TanhSquash(torch.tensor([0.0, -3.0]), torch.tensor([1.0, 1.0]))
    u = torch.tensor([[0.0, 0.0], [0.7, -1.3]], requires_grad=True)
    # by hand: r (1 - tanh²(u)), r = (0.5, 2)
    expected = torch.tensor([0.5, 2.0]) * (1 - torch.tanh(u.detach()) ** 2)
    torch.testing.assert_close(squash.derivative(u), expected)
    torch.testing.assert_close(squash.derivative(u)[0], torch.tensor([0.5, 2.0]))
    (grad,) = torch.autograd.grad(squash(u).sum(), u)  # the Jacobian's diagonal
    torch.testing.assert_close(squash.derivative(u.detach()), grad)


def test_mean_jacobian_is_the_readout_scale_without_a_squash():
    actor = _Affine()
    head = torch.randn(4, 2)
    context = torch.randn(4, 3)
    torch.testing.assert_close(actor.mean_jacobian(head, context), torch.full((4, 2), 2.0))


def test_mean_jacobian_with_a_squash_is_the_chain_rule_at_the_readout():
    actor = _Affine()
    actor.squash = TanhSquash(-2.0, 2.0)
    head = torch.tensor([[0.1, -0.4], [0.3, 0.2]])
    context = torch.tensor([[0.5, -1.0, 9.0], [0.0, 0.25, 9.0]])
    # by hand: u = 2 h + s[:2]; ∂μ/∂h = 2 · 2 (1 - tanh²(u))
    u = 2.0 * head + context[:, :2]
    expected = 4.0 * (1 - torch.tanh(u) ** 2)
    torch.testing.assert_close(actor.mean_jacobian(head, context), expected)
    h = head.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(actor.act(h, context).sum(), h)
    torch.testing.assert_close(actor.mean_jacobian(head, context), grad)


def test_noise_after_squash_needs_a_squash_with_a_derivative():
    with pytest.raises(
        ValueError,
        match=r"^noise_after_squash=True needs a squash with a derivative\(\) \(e\.g\. "
        r"TanhSquash\), got NoneType\.$",
    ):
        LastLayerActor(2, noise_after_squash=True)
    with pytest.raises(ValueError, match=r"got Tanh\.$"):
        LastLayerActor(2, squash=nn.Tanh(), noise_after_squash=True)
    squash = TanhSquash()
    actor = LastLayerActor(2, squash=squash, noise_after_squash=True)
    assert actor.noise_after_squash is True and actor.squash is squash
    assert LastLayerActor(2, squash=squash).noise_after_squash is False


def test_init_std_may_sit_on_either_bound():
    torch.testing.assert_close(LastLayerActor(2, init_std=1e-3).std, torch.full((2,), 1e-3))
    torch.testing.assert_close(LastLayerActor(2, init_std=2.0).std, torch.full((2,), 2.0))


def test_features_default_to_the_first_output_of_encode():
    class EncodeOnly(LastLayerActor):
        def encode(self, observation):
            return observation * 3.0, observation + 1.0

    observation = torch.tensor([[1.0, -2.0]])
    torch.testing.assert_close(EncodeOnly(2).features(observation), torch.tensor([[3.0, -6.0]]))
