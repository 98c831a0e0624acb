"""The actor's policy query and a separate (frozen) transition model in one batched pass."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from torch import nn

from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser
from torchrl_dual.modules import PlannerActor, TransitionModel
from torchrl_dual.diffusion._fast_path.paired_trunk import PairedTrunk
from torchrl_dual.objectives import WeightedMAPActorLoss


def _pair(make_model):
    torch.manual_seed(0)
    model = make_model(num_steps=1)
    model.normalizer.fit(torch.randn(256, 3) * 2 + 1, torch.randn(256, 2) * 0.5)
    frozen = copy.deepcopy(model)
    with torch.no_grad():  # the actor has been fine-tuned away from the distilled copy
        for parameter in model.parameters():
            parameter.add_(0.05 * torch.randn_like(parameter))
    return PlannerActor(model, transition_model=frozen), frozen


def _inputs(*batch, seed=1):
    gen = torch.Generator().manual_seed(seed)
    return (
        torch.randn(*batch, 3, generator=gen) * 2 + 1,
        torch.randn(*batch, 3, generator=gen) * 2 + 1,
        torch.randn(*batch, 2, generator=gen) * 0.5,
    )


def _check(actor, frozen, observation, previous_observation, previous_action):
    with torch.no_grad():
        features, context, predicted = actor.encode_with_transition(
            observation, previous_observation, previous_action
        )
        reference = TransitionModel(frozen).predict(previous_observation, previous_action)
        shared = PlannerActor(actor.model).encode_with_transition(
            observation, previous_observation, previous_action
        )[2]
    with torch.enable_grad():
        alone = actor.features(observation).detach()
    torch.testing.assert_close(features, alone, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(predicted, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(context, observation)
    assert not torch.allclose(predicted, shared, atol=1e-3)  # not the actor's own weights


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
def test_one_pass_gives_the_actor_features_and_the_frozen_models_prediction(make_model, batch):
    actor, frozen = _pair(make_model)
    _check(actor, frozen, *_inputs(*batch))


def test_the_paired_pass_follows_actor_training_and_leaves_the_transition_model_frozen(
    make_model,
):
    actor, frozen = _pair(make_model)
    before = copy.deepcopy(frozen.state_dict())
    loss = WeightedMAPActorLoss(actor, weighting="uniform")
    optimizer = torch.optim.Adam(loss.parameters(), lr=0.05)
    observation, previous_observation, previous_action = _inputs(8)
    _check(actor, frozen, observation, previous_observation, previous_action)  # fills caches
    batch = TensorDict(observation=observation, action=torch.randn(8, 2), batch_size=[8])
    for _ in range(3):
        optimizer.zero_grad()
        loss(batch)["loss_actor"].backward()
        assert all(p.grad is None for p in frozen.parameters())
        optimizer.step()
    for key, value in frozen.state_dict().items():
        torch.testing.assert_close(value, before[key])
    _check(actor, frozen, observation, previous_observation, previous_action)


def test_the_transition_model_is_registered_frozen_and_follows_dtype_changes(make_model):
    actor, frozen = _pair(make_model)
    assert any(key.startswith("transition_model.") for key in actor.state_dict())
    assert not any(p.requires_grad for p in frozen.parameters())
    actor.double()
    _check(actor, frozen, *(x.double() for x in _inputs(4)))


def test_bad_transition_models_are_rejected(make_model):
    model = make_model(num_steps=1)
    with pytest.raises(ValueError, match="omit it to share"):
        PlannerActor(model, transition_model=model)
    with pytest.raises(ValueError, match="one-step planner with the actor's layout"):
        PlannerActor(model, transition_model=make_model(num_steps=4))


def test_paired_trunk_equals_two_trunks_and_rebuilds_after_either_changes():
    torch.manual_seed(0)
    first, second = (ResidualMLPDenoiser((3, 4), hidden=16, depth=2) for _ in range(2))
    trunk = PairedTrunk(first, second)
    hidden = torch.randn(2, 7, 16)

    def check():
        with torch.no_grad():
            out = trunk(hidden)
            torch.testing.assert_close(out[0], first.trunk(hidden[0]))
            torch.testing.assert_close(out[1], second.trunk(hidden[1]))

    check()
    with torch.no_grad():
        second.blocks[1].net[3].weight.mul_(2.0)
        first.output_norm[0].bias.add_(1.0)
    check()
    first.load_state_dict(ResidualMLPDenoiser((3, 4), hidden=16, depth=2).state_dict(), assign=True)
    check()
    other = ResidualMLPDenoiser((3, 4), hidden=16, depth=1)
    with pytest.raises(ValueError, match="same width and depth"):
        PairedTrunk(first, other)
    other.blocks[0].net = nn.Sequential(nn.Linear(16, 16))
    with pytest.raises(TypeError, match="residual blocks"):
        PairedTrunk(first, other)
