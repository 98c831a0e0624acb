"""TorchRL's DiffusionActor wrapped as a last-layer actor ("Diff-QL w LA", paper Fig. 4c)."""

from __future__ import annotations

import copy
import math

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


def _reference_chain(sampler, observation, x, *, noisy=False):
    """A naive DDPM chain from ``x_N = x`` down to the action (``t = N-1 … 0``), the
    schedule recomputed from ``betas``; with ``noisy``, ``√β_t ξ`` after every step but the
    last, ``ξ`` drawn from the global generator in the chain's order."""
    betas = sampler.betas
    alphas = 1.0 - betas
    alpha_bars = torch.cumprod(alphas, 0)
    for t in range(STEPS - 1, -1, -1):
        step = torch.full((*observation.shape[:-1], 1), float(t))
        epsilon = sampler.score_network(torch.cat([x, observation, step], dim=-1))
        x = (x - betas[t] / torch.sqrt(1 - alpha_bars[t]) * epsilon) / torch.sqrt(alphas[t])
        if noisy and t > 0:
            x = x + torch.sqrt(betas[t]) * torch.randn_like(x)
    return x


def test_sample_latent_is_the_noisy_ddpm_chain_from_a_drawn_latent():
    diffusion = _diffusion()
    actor = DDPMLastStepActor(diffusion, latent="sample")
    observation = torch.randn(5, OBS)
    with torch.no_grad():
        torch.manual_seed(7)
        action = actor(observation)
        torch.manual_seed(7)
        latent = torch.randn(5, ACT)
        expected = _reference_chain(diffusion.module, observation, latent, noisy=True)
    torch.testing.assert_close(action, expected, rtol=1e-5, atol=1e-5)


def test_zero_latent_is_the_noiseless_chain_from_zero():
    diffusion = _diffusion()
    observation = torch.randn(5, OBS)
    with torch.no_grad():
        expected = _reference_chain(diffusion.module, observation, torch.zeros(5, ACT))
        action = DDPMLastStepActor(diffusion)(observation)
    torch.testing.assert_close(action, expected, rtol=1e-5, atol=1e-5)


def test_observations_with_several_batch_dimensions_act_like_a_flat_batch():
    diffusion = _diffusion()
    observation = torch.randn(2, 4, OBS)
    with torch.no_grad():
        action = DDPMLastStepActor(diffusion)(observation)
        flat = _reference_chain(diffusion.module, observation.reshape(8, OBS), torch.zeros(8, ACT))
    assert action.shape == (2, 4, ACT)
    torch.testing.assert_close(action, flat.reshape(2, 4, ACT), rtol=1e-5, atol=1e-5)


def test_a_float64_schedule_is_cast_to_the_actor_dtype():
    diffusion = _diffusion()
    observation = torch.randn(3, OBS)
    with torch.no_grad():
        expected = _reference_chain(diffusion.module, observation, torch.zeros(3, ACT))
        sampler = diffusion.module
        for name in ("betas", "alphas", "alphas_cumprod"):
            setattr(sampler, name, getattr(sampler, name).double())
        action = DDPMLastStepActor(diffusion)(observation)
    assert action.dtype == torch.float32
    torch.testing.assert_close(action, expected, rtol=1e-5, atol=1e-5)


def test_wrapping_the_actor_or_its_ddpm_module_gives_the_same_actor():
    """Docstring: a ``DiffusionActor`` or its ``module``; the checkpoint keys and the mean
    are the same either way."""
    diffusion = _diffusion()
    from_actor, from_module = DDPMLastStepActor(diffusion), DDPMLastStepActor(diffusion.module)
    assert list(from_actor.state_dict()) == list(from_module.state_dict())
    assert any(key.startswith("sampler.score_network.") for key in from_module.state_dict())
    observation = torch.randn(4, OBS)
    with torch.no_grad():
        torch.testing.assert_close(from_module(observation), from_actor(observation))


def test_keyword_arguments_reach_the_last_layer_actor():
    actor = DDPMLastStepActor(_diffusion(), init_std=0.5, max_std=0.8)
    torch.testing.assert_close(actor.std, torch.full((ACT,), 0.5))
    assert actor.max_log_std == pytest.approx(math.log(0.8))


class _Wrapped(nn.Module):
    """A score network that is not an ``nn.Sequential`` but whose last child is a Linear."""

    def __init__(self) -> None:
        super().__init__()
        self.net = nn.Linear(OBS + ACT + 1, ACT)

    def forward(self, x):
        return self.net(x)


def test_rejections_name_the_offending_module_and_the_fix():
    with pytest.raises(
        TypeError,
        match=r"^DDPMLastStepActor wraps torchrl\.modules\.DiffusionActor \(or its DDPM "
        r"module\); Linear lacks \['score_network', 'betas'",
    ):
        DDPMLastStepActor(nn.Linear(3, 2))
    diffusion = _diffusion()
    diffusion.module.score_network = _Wrapped()
    with pytest.raises(
        TypeError,
        match=r"^DDPMLastStepActor needs a score_network that is an nn\.Sequential ending in "
        r"nn\.Linear \(the ε̂ head\), got _Wrapped\.$",
    ):
        DDPMLastStepActor(diffusion)
    lazy = DiffusionActor(action_dim=ACT, num_steps=STEPS)
    with pytest.raises(
        ValueError,
        match=r"^The score network still has lazy \(uninitialised\) layers: pass obs_dim= to "
        r"DiffusionActor, or run it once on an observation before wrapping it\.$",
    ):
        DDPMLastStepActor(lazy)


def test_the_readout_scale_is_in_the_head_dtype_and_device_whatever_the_schedule():
    """``β_0 / (√α_0 √(1 − ᾱ_0))`` (hand computation from ``betas``), cast to the head's dtype
    with a float64 schedule and moved to the head's device."""
    diffusion = _diffusion()
    betas = diffusion.module.betas
    # ᾱ_0 = α_0 = 1 − β_0, so 1 − ᾱ_0 = β_0
    expected = betas[0] / (torch.sqrt(1 - betas[0]) * torch.sqrt(betas[0]))
    sampler = diffusion.module
    for name in ("betas", "alphas", "alphas_cumprod"):
        setattr(sampler, name, getattr(sampler, name).double())
    actor = DDPMLastStepActor(diffusion)
    scale = actor.readout_scale()
    assert scale.dtype == torch.float32
    torch.testing.assert_close(scale, expected.expand(ACT))
    assert actor.mean_jacobian(torch.zeros(4, ACT), torch.zeros(4, ACT)).dtype == torch.float32
    sampler.score_network.to("meta")  # the schedule stays on the CPU
    assert actor.readout_scale().device.type == "meta"
