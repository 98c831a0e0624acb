"""Classifier guidance of the planner (``torchrl_dual/diffusion/guidance.py``).

The closed form: windows ``x ~ N(0, I)`` have the exact denoiser ``E[x | z_t] = α_t z_t``
(``v̂ = 0``); "online" windows ``x ~ N(μ, I)`` noise to ``z_t ~ N(α_t μ, I)``, so the exact
noisy log density ratio is ``α_t μ·z − const`` and guidance with scale 1 must sample
``N(μ, I)``, up to the sampler's discretisation, which vanishes as the steps grow.
"""

from __future__ import annotations

import pytest
import torch
from torch import nn

from torchrl_dual.diffusion import (
    NoisyWindowClassifier,
    TrajectoryDiffusion,
    TrajectoryLayout,
    classifier_guidance,
    density_ratio_loss,
)

LAYOUT = TrajectoryLayout(obs_dim=1, action_dim=1, horizon=2)
MU = 1.0  # the online windows' mean on every entry


class ExactGaussianDenoiser(nn.Module):
    """``v̂ = 0``: ``x̂ = α_t z_t = E[x | z_t]`` for ``x ~ N(0, I)``."""

    def forward(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return torch.zeros_like(z)


class ExactLogRatio(nn.Module):
    """``log N(z; α_t μ, I) / N(z; 0, I) = α_t μ·z − α_t² |μ|² / 2``."""

    def __init__(self, model: TrajectoryDiffusion) -> None:
        super().__init__()
        self.model = model

    def forward(self, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        alpha, _ = self.model.schedule(t)
        flat = z.flatten(-2)
        return alpha * MU * flat.sum(-1) - alpha**2 * MU**2 * flat.shape[-1] / 2


def gaussian_planner(num_steps: int) -> TrajectoryDiffusion:
    return TrajectoryDiffusion(LAYOUT, ExactGaussianDenoiser(), num_steps=num_steps)


def sample(model, num, mean_shift=None, seed=0, s0=3.0):
    cond, mask = LAYOUT.conditioned_window(torch.full((num, 1), s0))
    generator = torch.Generator().manual_seed(seed)
    x = model.sample(cond, mask, sampler="ddpm", generator=generator, mean_shift=mean_shift)
    return x, cond, mask


def test_exact_guidance_samples_the_reweighted_gaussian_as_the_steps_grow():
    errors = []
    for num_steps in (16, 128):
        model = gaussian_planner(num_steps)
        x, _, mask = sample(model, 4000, classifier_guidance(ExactLogRatio(model), 1.0))
        errors.append(abs(float(x[~mask].mean()) - MU))
    assert errors[1] < 0.1  # N(μ, I): measured mean 0.94 at 128 steps
    assert errors[1] < errors[0] / 2  # the discretisation error shrinks


def test_the_guidance_scale_scales_the_shift_and_zero_is_the_unguided_sampler_bit_for_bit():
    model = gaussian_planner(16)
    guide = ExactLogRatio(model)
    unguided, _, mask = sample(model, 2000)
    zero, _, _ = sample(model, 2000, classifier_guidance(guide, 0.0))
    assert torch.equal(zero, unguided)
    means = [float(sample(model, 2000, classifier_guidance(guide, s))[0][~mask].mean())
             for s in (0.5, 1.0)]  # fmt: skip
    assert abs(float(unguided[~mask].mean())) < 0.1
    assert 0.2 < means[0] < means[1]


def test_guidance_keeps_the_inpainted_s0_exact_and_needs_ddpm():
    model = gaussian_planner(8)
    shift = classifier_guidance(ExactLogRatio(model), 5.0)
    x, cond, mask = sample(model, 64, shift, s0=-2.5)
    assert torch.equal(x[mask], cond[mask])
    with pytest.raises(ValueError, match="needs sampler='ddpm'"):
        model.sample(cond, mask, sampler="ddim", mean_shift=shift)


def test_a_trained_classifier_guides_the_samples_toward_the_online_windows():
    """The logistic loss on noisy windows, offline N(0, I) vs online N(μ, I), learns a
    logit whose guidance moves the samples toward μ (same seed, unguided stays at 0); the
    classifier's weights get no gradient from sampling."""
    torch.manual_seed(0)
    model = gaussian_planner(16)
    classifier = NoisyWindowClassifier(LAYOUT.window_shape, hidden=32, depth=1)
    optimizer = torch.optim.Adam(classifier.parameters(), lr=3e-3)
    mask = LAYOUT.condition_mask("s0")
    for _ in range(300):
        offline = torch.randn(128, *LAYOUT.window_shape)
        online = torch.randn(128, *LAYOUT.window_shape) + MU
        loss, accuracy = density_ratio_loss(classifier, model, offline, online, mask)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    assert float(accuracy) > 0.6  # at t near 1 no classifier can tell them apart
    optimizer.zero_grad(set_to_none=True)
    guided, _, full_mask = sample(model, 2000, classifier_guidance(classifier, 1.0))
    unguided, _, _ = sample(model, 2000)
    assert all(p.grad is None for p in classifier.parameters())
    assert float(guided[~full_mask].mean()) > 0.3  # exact log-ratio at 16 steps: 0.65
    assert abs(float(unguided[~full_mask].mean())) < 0.1
