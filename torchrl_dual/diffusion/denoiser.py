"""Residual-MLP denoiser over the flattened trajectory window."""

from __future__ import annotations

import math

import torch
from torch import nn


class SinusoidalTimeEmbedding(nn.Module):
    """Transformer-style sinusoidal features of a diffusion time ``t ∈ [0, 1]``.

    Args:
        dim (int): size of the embedding (even): ``dim / 2`` frequencies
            ``f_k = max_period^(-k / (dim / 2))``, each giving a sine and a cosine.
        max_period (float): the longest period. Defaults to ``10_000``.

    Examples:
        >>> import torch
        >>> features = SinusoidalTimeEmbedding(8)(torch.tensor([0.0, 0.5]))
        >>> features.shape
        torch.Size([2, 8])
        >>> features[0].tolist()  # t = 0: every sine 0, every cosine 1
        [0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0]
    """

    def __init__(self, dim: int, max_period: float = 10_000.0) -> None:
        super().__init__()
        if dim % 2:
            raise ValueError(f"time embedding dim must be even, got {dim}.")
        half = dim // 2
        freqs = torch.exp(-math.log(max_period) * torch.arange(half) / half)
        self.register_buffer("freqs", freqs)

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        """The features ``[sin(1000 t f_k), cos(1000 t f_k)]`` of ``t``.

        Args:
            t (Tensor): diffusion times in ``[0, 1]``, ``[*B]``.

        Returns:
            The embedding, ``[*B, dim]``: the sines of every frequency, then the cosines.
        """
        angles = (1000.0 * t)[..., None] * self.freqs
        return torch.cat([angles.sin(), angles.cos()], dim=-1)


class _ResidualBlock(nn.Module):
    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.LayerNorm(hidden),
            nn.Linear(hidden, hidden),
            nn.SiLU(),
            nn.Linear(hidden, hidden),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.net(x)


class ResidualMLPDenoiser(nn.Module):
    """Predicts the diffusion target ``v`` of a whole window in one MLP pass.

    The window is flattened; the network sees the noisy window (with known entries
    replaced by their clean values), the conditioning mask and a time embedding.
    It is split into :meth:`features` (the trunk ``φ``) and :attr:`head` (the
    final ``nn.Linear``), the split the last-layer Laplace approximation (Eq. 8)
    works on.

    ===============  ===================  ======================================
    argument         shape                meaning
    ===============  ===================  ======================================
    ``z``            ``[*B, L, D]``       noisy window, known entries clean
    ``t``            ``[*B]``             diffusion time in ``[0, 1]``
    ``mask``         ``[*B, L, D]`` bool  known (conditioned) entries
    output           ``[*B, L, D]``       prediction ``v̂``
    ===============  ===================  ======================================

    Args:
        window_shape (tuple[int, int]): ``(L, D) = (H + 1, obs_dim + action_dim)``.

    Keyword Args:
        hidden (int): trunk width. Defaults to ``256``.
        depth (int): number of residual blocks. Defaults to ``3``.
        time_dim (int): size of the sinusoidal time embedding. Defaults to ``64``.

    Examples:
        >>> import torch
        >>> net = ResidualMLPDenoiser((9, 6), hidden=64, depth=2)
        >>> z, t = torch.randn(5, 9, 6), torch.rand(5)
        >>> mask = torch.zeros(5, 9, 6, dtype=torch.bool)
        >>> net(z, t, mask).shape
        torch.Size([5, 9, 6])
    """

    def __init__(
        self,
        window_shape: tuple[int, int],
        *,
        hidden: int = 256,
        depth: int = 3,
        time_dim: int = 64,
    ) -> None:
        super().__init__()
        self.window_shape = tuple(window_shape)
        flat = self.window_shape[0] * self.window_shape[1]
        self.time_embedding = nn.Sequential(
            SinusoidalTimeEmbedding(time_dim), nn.Linear(time_dim, hidden), nn.SiLU()
        )
        self.input_layer = nn.Linear(2 * flat, hidden)
        self.blocks = nn.Sequential(*[_ResidualBlock(hidden) for _ in range(depth)])
        self.output_norm = nn.Sequential(nn.LayerNorm(hidden), nn.SiLU())
        self.head = nn.Linear(hidden, flat)
        self.feature_dim = hidden

    def features(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """The trunk ``φ(z, t, mask)`` of shape ``[*B, hidden]``."""
        if z.shape[-2:] != self.window_shape:
            raise ValueError(
                f"Denoiser expects windows of shape [..., {self.window_shape[0]}, "
                f"{self.window_shape[1]}], got {tuple(z.shape)}."
            )
        flat_z = z.flatten(-2)
        flat_mask = mask.to(z.dtype).expand_as(z).flatten(-2)
        hidden = self.input_layer(torch.cat([flat_z, flat_mask], dim=-1))
        hidden = hidden + self.time_embedding(t.to(z.dtype))
        return self.trunk(hidden)

    def trunk(self, hidden: torch.Tensor) -> torch.Tensor:
        """The residual blocks and output norm on the first layer's output, ``[*B, hidden]``.

        The first layer's output is ``input_layer(z, mask) + time_embedding(t)``.
        """
        return self.output_norm(self.blocks(hidden))

    def trunk_layers(self) -> tuple[list[tuple[nn.LayerNorm, nn.Linear, nn.Linear]], nn.LayerNorm]:
        """The parametrised layers of :meth:`trunk`, in order.

        ``(norm, linear_1, linear_2)`` of each residual block ``x +
        linear_2(SiLU(linear_1(norm(x))))``, then the output norm (followed by
        SiLU). A fused re-implementation of the trunk reads these.
        """
        blocks = [(block.net[0], block.net[1], block.net[3]) for block in self.blocks]
        return blocks, self.output_norm[0]

    def forward(self, z: torch.Tensor, t: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Predicts the diffusion target ``v̂`` of the whole window, ``head(φ(z, t, mask))``.

        Args:
            z (Tensor): the noisy window, known entries clean, ``[*B, L, D]``.
            t (Tensor): the diffusion time in ``[0, 1]``, ``[*B]``.
            mask (Tensor): the known (conditioned) entries, bool, ``[*B, L, D]`` (or
                broadcastable to it).

        Returns:
            ``v̂``, ``[*B, L, D]``.
        """
        out = self.head(self.features(z, t, mask))
        return out.unflatten(-1, self.window_shape)
