"""Energy guidance of the planner toward the online distribution (EDIS's guider).

EDIS (Liu et al. 2024, "Energy-Guided Diffusion Sampling for Offline-to-Online RL"; the
DUAL paper's Section 2.2 and Algorithm 1's grey line 14) samples windows from

``p_online(τ) ∝ p_offline(τ) · q_online(τ) / q_offline(τ) = p_offline(τ) · e^{−ε(τ)}``,

the planner ``p_offline`` trained on ``D_offline`` reweighted by the density ratio of
online to offline windows (``ε(τ) = −log q_online(τ)/q_offline(τ)`` is the energy). The
ratio comes from a classifier: trained with the logistic loss on as many offline
(label 0) as online (label 1) windows, its logit ``f(τ)`` converges to
``log q_online(τ) / q_offline(τ)`` (the density-ratio trick).

Sampling uses classifier guidance (Dhariwal & Nichol 2021; Diffuser's value guide,
Janner et al. 2022): the classifier sees noisy windows ``z_t = α_t τ + σ_t ε`` at random
diffusion times, as the planner does, so ``f(z_t, t) ≈ log q_online_t(z_t) / q_offline_t(z_t)``
for the noised marginals, and each ancestral (DDPM) step's posterior mean is shifted by
``s · Σ_t · ∇_z f(z_t, t)`` (:func:`classifier_guidance`, passed to
:meth:`TrajectoryDiffusion.sample` as ``mean_shift``). ``s = 1`` targets the product
above; ``s = 0`` is the unguided planner. EDIS trains its energy function by contrastive
energy prediction and guides with its intermediate energies; this module keeps the
classifier-guidance form of the same target, which needs no extra network per time step.

The known entries (``s_0``) are clean in the classifier's input, as the sampler writes
them into ``z_t``; the guidance never moves them.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from torchrl_dual.diffusion.denoiser import SinusoidalTimeEmbedding
from torchrl_dual.diffusion.model import MeanShift, TrajectoryDiffusion


class NoisyWindowClassifier(nn.Module):
    """The logit ``f(z_t, t)`` of "online" for a noisy normalized window.

    An MLP over the flattened window plus a sinusoidal embedding of ``t``; trained with
    :func:`density_ratio_loss`, ``f`` estimates ``log q_online_t(z_t) / q_offline_t(z_t)``.

    Args:
        window_shape (tuple[int, int]): ``(H + 1, obs_dim + action_dim)``.

    Keyword Args:
        hidden (int): MLP width. Defaults to ``128``.
        depth (int): hidden layers after the input layer. Defaults to ``2``.
        time_dim (int): size of the time embedding. Defaults to ``32``.

    Examples:
        >>> import torch
        >>> f = NoisyWindowClassifier((5, 3), hidden=16)
        >>> f(torch.randn(4, 5, 3), torch.rand(4)).shape
        torch.Size([4])
    """

    def __init__(
        self,
        window_shape: tuple[int, int],
        *,
        hidden: int = 128,
        depth: int = 2,
        time_dim: int = 32,
    ) -> None:
        super().__init__()
        self.window_shape = tuple(window_shape)
        self.input_layer = nn.Linear(self.window_shape[0] * self.window_shape[1], hidden)
        self.time_embedding = nn.Sequential(
            SinusoidalTimeEmbedding(time_dim), nn.Linear(time_dim, hidden)
        )
        layers: list[nn.Module] = []
        for _ in range(depth):
            layers += [nn.SiLU(), nn.Linear(hidden, hidden)]
        self.trunk = nn.Sequential(*layers, nn.SiLU())
        self.head = nn.Linear(hidden, 1)

    def forward(self, z: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """``[*B, L, D]`` windows at ``[*B]`` times -> ``[*B]`` logits."""
        if z.shape[-2:] != self.window_shape:
            raise ValueError(
                f"The classifier expects windows [..., {self.window_shape[0]}, "
                f"{self.window_shape[1]}], got {tuple(z.shape)}."
            )
        hidden = self.input_layer(z.flatten(-2)) + self.time_embedding(t.to(z.dtype))
        return self.head(self.trunk(hidden)).squeeze(-1)


def noisy_windows(
    model: TrajectoryDiffusion, x0: torch.Tensor, mask: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Noises ``x0`` by ``model``'s forward process at ``t ~ U(0, 1)``; returns ``(z_t, t)``.

    The ``mask`` entries are kept clean (as the sampler's inpainting keeps them).
    """
    t = torch.rand(x0.shape[:-2], device=x0.device)
    z = model.noise(x0, t, torch.randn_like(x0))
    return torch.where(mask, x0, z), t


def density_ratio_loss(
    classifier: nn.Module,
    model: TrajectoryDiffusion,
    offline: torch.Tensor,
    online: torch.Tensor,
    mask: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The logistic loss of "online" (1) vs "offline" (0) on noisy windows; and accuracy.

    ``offline`` and ``online`` are ``[B, L, D]`` normalized clean windows (give as many of
    each, so the optimal logit is the log density ratio with no prior-odds offset).

    Args:
        classifier (nn.Module): ``f(z_t, t) -> logit [B]`` on noisy windows, e.g. a
            :class:`NoisyWindowClassifier`.
        model (TrajectoryDiffusion): its forward process noises the windows
            (:func:`noisy_windows`).
        offline (Tensor): normalized clean offline windows, ``[B, L, D]``.
        online (Tensor): normalized clean online windows, ``[B, L, D]``.
        mask (Tensor): the known entries, kept clean, bool ``[L, D]`` (or broadcastable).

    Returns:
        tuple[Tensor, Tensor]: the mean binary cross-entropy (differentiable in the
        classifier's weights) and the detached accuracy, scalars.

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryLayout
        >>> layout = TrajectoryLayout(2, 1, 3)
        >>> model = TrajectoryDiffusion(layout, num_steps=4, hidden=16, depth=1)
        >>> f = NoisyWindowClassifier(layout.window_shape, hidden=16)
        >>> loss, accuracy = density_ratio_loss(
        ...     f, model, torch.randn(8, 4, 3), torch.randn(8, 4, 3) + 2,
        ...     layout.condition_mask("s0"))
        >>> loss.backward()
        >>> 0 <= float(accuracy) <= 1
        True
    """
    x0 = torch.cat([offline, online], 0)
    label = torch.cat([offline.new_zeros(offline.shape[0]), online.new_ones(online.shape[0])])
    z, t = noisy_windows(model, x0, mask.expand_as(x0))
    logit = classifier(z, t)
    loss = F.binary_cross_entropy_with_logits(logit, label)
    accuracy = ((logit > 0).to(label.dtype) == label).to(label.dtype).mean().detach()
    return loss, accuracy


def classifier_guidance(classifier: nn.Module, scale: float) -> MeanShift:
    """The mean shift ``Δμ = scale · Σ · ∇_z f(z_t, t)`` of classifier guidance.

    Pass it as ``mean_shift`` to :meth:`TrajectoryDiffusion.sample` (``sampler="ddpm"``).
    The gradient is taken with respect to the window only: the classifier's weights get
    no gradient, and sampling under ``torch.no_grad()`` works.

    Args:
        classifier (nn.Module): ``f(z_t, t) -> [B]``, differentiable in ``z_t``.
        scale (float): the guidance scale.

    Returns:
        MeanShift: ``(z_t, t, Σ) -> Δμ``, shaped like ``z_t``.

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryLayout
        >>> layout = TrajectoryLayout(2, 1, 3)
        >>> model = TrajectoryDiffusion(layout, num_steps=4, hidden=16, depth=1)
        >>> f = NoisyWindowClassifier(layout.window_shape, hidden=16)
        >>> cond, mask = layout.conditioned_window(torch.randn(5, 2))
        >>> with torch.no_grad():
        ...     x = model.sample(cond, mask, sampler="ddpm",
        ...                      mean_shift=classifier_guidance(f, scale=1.0))
        >>> torch.equal(x[:, 0, :2], cond[:, 0, :2])
        True
    """

    def shift(z: torch.Tensor, t: torch.Tensor, variance: torch.Tensor) -> torch.Tensor:
        with torch.enable_grad():
            z = z.detach().requires_grad_(True)
            (grad,) = torch.autograd.grad(classifier(z, t.detach()).sum(), z)
        return scale * variance * grad

    return shift
