"""TorchRL's DiffusionActor wrapped as a last-layer actor ("Diff-QL w LA", paper Fig. 4c)."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import InteractionType, set_interaction_type
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import DiffusionActor
from torchrl.objectives import DiffusionBCLoss

from torchrl_dual.modules import DDPMLastStepActor, LaplaceEnsembleActor

OBS, ACT, STEPS = 3, 2, 10


def _diffusion(seed: int = 0) -> DiffusionActor:
    torch.manual_seed(seed)
    return DiffusionActor(action_dim=ACT, obs_dim=OBS, num_steps=STEPS)


def test_zero_latent_mean_equals_the_deterministic_diffusion_actor():
    diffusion = _diffusion()
    actor = DDPMLastStepActor(diffusion)
    observation = torch.randn(6, OBS)
    with set_interaction_type(InteractionType.DETERMINISTIC):
        reference = diffusion(TensorDict(observation=observation, batch_size=[6]))["action"]
    torch.testing.assert_close(actor(observation), reference, rtol=1e-5, atol=1e-6)


def test_mean_is_affine_in_the_head_and_readout_scale_is_its_derivative():
    actor = DDPMLastStepActor(_diffusion())
    observation = torch.randn(5, OBS)
    features, context = actor.encode(observation)
    head = actor.head_output(features)
    delta = 0.3
    shifted = actor.readout(head + delta, context) - actor.readout(head, context)
    torch.testing.assert_close(shifted.abs() / delta, actor.readout_scale().expand(5, ACT))
    gen = torch.Generator().manual_seed(3)
    w1, w2 = (torch.randn(actor.head.weight.shape, generator=gen) * 0.1 for _ in range(2))
    means = []
    for weight in (w1, w2, (w1 + w2) / 2):
        twin = copy.deepcopy(actor)
        with torch.no_grad():
            twin.head.weight.copy_(weight)
        # hold x_1 at the original chain: the last step alone is affine in the head
        means.append(twin.readout(twin.head_output(features), context))
    torch.testing.assert_close(means[2], (means[0] + means[1]) / 2, rtol=1e-5, atol=1e-6)


def test_the_chain_runs_once_for_all_ensemble_members():
    actor = DDPMLastStepActor(_diffusion())
    policy = LaplaceEnsembleActor(actor, num_samples=16)
    policy.fit_laplace([TensorDict(observation=torch.randn(128, OBS), batch_size=[128])])
    calls = []
    first = actor.trunk[0]
    handle = first.register_forward_hook(lambda *args: calls.append(1))
    with torch.no_grad():
        out = policy(TensorDict(observation=torch.randn(7, OBS), batch_size=[7]))
    handle.remove()
    assert len(calls) == STEPS  # N - 1 chain steps + the last step's trunk
    assert out["action"].shape == out["epistemic_variance"].shape == (7, ACT)
    assert (out["epistemic_variance"] > 0).all()


def test_sample_latent_draws_a_different_chain_each_call():
    actor = DDPMLastStepActor(_diffusion(), latent="sample")
    observation = torch.randn(4, OBS)
    with torch.no_grad():
        assert not torch.allclose(actor(observation), actor(observation))


def test_diff_ql_with_la_is_more_uncertain_away_from_its_data():
    """Train the diffusion actor with TorchRL's DiffusionBCLoss, then fit Eq. 8 on its data."""
    diffusion = _diffusion(1)
    loss = DiffusionBCLoss(diffusion)
    optimizer = torch.optim.Adam(loss.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(0)
    for _ in range(150):
        observation = torch.rand(256, OBS, generator=gen) * 2 - 1
        action = torch.stack([observation[:, 0].sin(), observation[:, 1] * 0.5], dim=-1)
        value = loss(TensorDict(observation=observation, action=action, batch_size=[256]))
        optimizer.zero_grad()
        value["loss_diffusion_bc"].backward()
        optimizer.step()
    policy = LaplaceEnsembleActor(DDPMLastStepActor(diffusion), num_samples=64)
    data = TensorDict(observation=torch.rand(2048, OBS, generator=gen) * 2 - 1, batch_size=[2048])
    policy.fit_laplace([data])
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        inside = policy(TensorDict(observation=torch.rand(256, OBS) * 2 - 1, batch_size=[256]))
        outside = policy(TensorDict(observation=torch.rand(256, OBS) * 2 + 4, batch_size=[256]))
    ratio = outside["epistemic_variance"].mean() / inside["epistemic_variance"].mean()
    print(f"epistemic variance off the data / on it: {ratio:.1f}")
    assert ratio > 3.0, f"epistemic variance only {ratio:.2f}x larger off the data"


def test_bad_actors_are_rejected_with_the_fix():
    with pytest.raises(TypeError, match="lacks"):
        DDPMLastStepActor(nn.Linear(3, 2))
    lazy = DiffusionActor(action_dim=ACT, num_steps=STEPS)  # LazyLinear first layer
    with pytest.raises(ValueError, match="obs_dim="):
        DDPMLastStepActor(lazy)
    diffusion = _diffusion()
    diffusion.module.score_network = nn.Sequential(nn.Linear(6, 8), nn.Tanh())
    with pytest.raises(TypeError, match="ending in nn.Linear"):
        DDPMLastStepActor(diffusion)
    with pytest.raises(ValueError, match="Unknown latent"):
        DDPMLastStepActor(_diffusion(), latent="mean")
