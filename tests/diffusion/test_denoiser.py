"""Tests of ``ResidualMLPDenoiser`` and ``SinusoidalTimeEmbedding``
(``torchrl_dual/diffusion/denoiser.py``): the split into trunk ``φ`` and head the last-layer
Laplace works on, and the layer list a fused re-implementation of the trunk reads."""

from __future__ import annotations

import pytest
import torch
from torch.nn import functional as F  # noqa: N812

from torchrl_dual.diffusion import ResidualMLPDenoiser, SinusoidalTimeEmbedding


def _denoiser(depth: int = 2) -> ResidualMLPDenoiser:
    torch.manual_seed(0)
    return ResidualMLPDenoiser((5, 4), hidden=16, depth=depth, time_dim=8)


def test_forward_is_the_head_of_the_features_unflattened():
    net = _denoiser()
    z, t = torch.randn(3, 5, 4), torch.rand(3)
    mask = torch.rand(3, 5, 4) < 0.3
    features = net.features(z, t, mask)
    assert features.shape == (3, 16) and net.feature_dim == 16
    torch.testing.assert_close(net(z, t, mask), net.head(features).view(3, 5, 4))


@pytest.mark.parametrize("depth", [1, 3])
def test_trunk_layers_in_order_reimplement_the_trunk(depth):
    net = _denoiser(depth)
    blocks, output_norm = net.trunk_layers()
    assert len(blocks) == depth
    hidden = torch.randn(6, 16)
    h = hidden
    for norm, linear_1, linear_2 in blocks:
        h = h + linear_2(F.silu(linear_1(norm(h))))
    torch.testing.assert_close(F.silu(output_norm(h)), net.trunk(hidden))
    assert all(layer.weight.requires_grad for block in blocks for layer in block)


def test_a_window_of_the_wrong_shape_shows_expected_and_given_shapes():
    with pytest.raises(ValueError, match=r"\[\.\.\., 5, 4\], got \(3, 4, 4\)"):
        _denoiser().features(torch.randn(3, 4, 4), torch.rand(3), torch.zeros(3, 4, 4, dtype=bool))


def test_the_time_embedding_is_sin_and_cos_of_scaled_times():
    embedding = SinusoidalTimeEmbedding(4, max_period=100.0)
    t = torch.tensor([0.0, 0.25])
    freqs = torch.tensor([1.0, 0.1])  # exp(-log(100) · [0, 1] / 2)
    angles = 1000.0 * t[:, None] * freqs
    torch.testing.assert_close(embedding(t), torch.cat([angles.sin(), angles.cos()], dim=-1))
    with pytest.raises(ValueError, match="even, got 5"):
        SinusoidalTimeEmbedding(5)
