"""The folded first layer of the one-step actor equals the general path, and follows weight changes."""

from __future__ import annotations

import copy

import pytest
import torch

from torchrl_dual.modules import PlannerActor, TransitionModel


def _actor(make_model, seed: int = 0) -> PlannerActor:
    torch.manual_seed(seed)
    model = make_model(num_steps=1)
    gen = torch.Generator().manual_seed(seed)
    model.normalizer.fit(  # non-trivial mean and scale, so the folding of (μ, σ) matters
        torch.randn(256, 3, generator=gen) * torch.tensor([0.5, 2.0, 4.0]) + 3.0,
        torch.randn(256, 2, generator=gen) * 0.3 - 0.2,
    )
    return PlannerActor(model)


def _general(actor, observation, previous_observation=None, previous_action=None):
    """The unfolded path (autograd on), detached."""
    with torch.enable_grad():
        if previous_observation is None:
            return actor.features(observation).detach()
        out = actor.encode_with_transition(observation, previous_observation, previous_action)
        return tuple(x.detach() for x in out)


def _inputs(*batch, seed=1):
    gen = torch.Generator().manual_seed(seed)
    return (
        torch.randn(*batch, 3, generator=gen) * 2.0 + 3.0,
        torch.randn(*batch, 3, generator=gen) * 2.0 + 3.0,
        torch.randn(*batch, 2, generator=gen) * 0.3,
    )


@pytest.mark.parametrize("batch", [(), (7,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_folded_features_and_shared_pass_equal_the_general_path(make_model, batch):
    actor = _actor(make_model)
    observation, previous_observation, previous_action = _inputs(*batch)
    with torch.no_grad():
        folded = actor.features(observation)
        shared = actor.encode_with_transition(observation, previous_observation, previous_action)
        reference = TransitionModel(actor.model).predict(previous_observation, previous_action)
    torch.testing.assert_close(folded, _general(actor, observation), rtol=1e-5, atol=1e-5)
    general = _general(actor, observation, previous_observation, previous_action)
    for got, expected in zip(shared, general, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(shared[2], reference, rtol=1e-5, atol=1e-5)


def test_folded_tensors_are_reused_until_a_source_tensor_changes(make_model):
    actor = _actor(make_model)
    first = actor._fold.tensors()
    assert actor._fold.tensors() is first  # cache hit: nothing was recomputed
    with torch.no_grad():
        actor.model.denoiser.blocks[0].net[1].weight.add_(1.0)  # not an input of the fold
    assert actor._fold.tensors() is first
    with torch.no_grad():
        actor.model.denoiser.input_layer.bias.add_(1.0)
    assert actor._fold.tensors() is not first


@pytest.mark.parametrize(
    "change",
    ["adam", "adam_foreach", "load_state_dict", "normalizer_fit", "double"],
)
def test_folded_path_follows_every_kind_of_weight_change(make_model, change):
    actor = _actor(make_model)
    observation, previous_observation, previous_action = _inputs(5)
    with torch.no_grad():
        actor.encode_with_transition(observation, previous_observation, previous_action)
    if change.startswith("adam"):
        optimizer = torch.optim.Adam(actor.parameters(), lr=0.05, foreach=change == "adam_foreach")
        for _ in range(2):
            optimizer.zero_grad()
            target = torch.randn(5, 2)
            (actor(observation) - target).pow(2).mean().backward()
            optimizer.step()
    elif change == "load_state_dict":
        actor.load_state_dict(_actor(make_model, seed=3).state_dict())
    elif change == "normalizer_fit":
        actor.model.normalizer.fit(torch.randn(64, 3) * 5 - 1, torch.randn(64, 2) + 1)
    else:
        actor.double()
        observation, previous_observation, previous_action = (
            x.double() for x in (observation, previous_observation, previous_action)
        )
    with torch.no_grad():
        shared = actor.encode_with_transition(observation, previous_observation, previous_action)
        folded = actor.features(observation)
    general = _general(actor, observation, previous_observation, previous_action)
    for got, expected in zip(shared, general, strict=True):
        torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(folded, general[0], rtol=1e-5, atol=1e-5)


def test_a_deep_copy_folds_its_own_weights(make_model):
    actor = _actor(make_model)
    observation = _inputs(4)[0]
    with torch.no_grad():
        actor.features(observation)
        twin = copy.deepcopy(actor)
        twin.model.denoiser.input_layer.weight.mul_(-1.0)
        assert not torch.allclose(twin.features(observation), actor.features(observation))
        folded = twin.features(observation)
    torch.testing.assert_close(folded, _general(twin, observation), rtol=1e-5, atol=1e-5)
