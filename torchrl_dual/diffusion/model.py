"""The trajectory diffusion model: forward noising, prediction and samplers."""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser
from torchrl_dual.diffusion.normalizer import Normalizer
from torchrl_dual.diffusion.schedule import NoiseSchedule
from torchrl_dual.diffusion.trajectory_layout import TrajectoryLayout

SAMPLERS = ("ddim", "ddpm")
MeanShift = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
"""``(z_t, t, Σ) -> Δμ``: a shift of the DDPM posterior mean (classifier guidance)."""
# The one-step sampler's latent z_1: the mean (zero) latent, or drawn at every call.
LATENTS = ("zero", "sample")


class TrajectoryDiffusion(nn.Module):
    """A diffusion model over normalized trajectory windows with inpainting.

    The denoiser predicts ``v = α_t·ε − σ_t·x`` (Salimans & Ho 2022). From it,
    ``x̂ = α_t·z_t − σ_t·v̂`` and ``ε̂ = σ_t·z_t + α_t·v̂``; both stay finite at
    ``t = 1`` where ``α_t = 0``, which a one-step sampler and progressive
    distillation need (ε-prediction cannot recover ``x̂`` there). Minimising the
    v-error is Eq. 3's ε-error reweighted over time: all three share the
    minimiser ``E[x | z_t]``.

    Conditioning (the ``τ_{s_0} = s`` of Eq. 5, and ``τ_{a_0} = a`` for the
    transition model) is inpainting: known entries are written into the network
    input, the network also sees the mask, and the known values are written back
    after every step, so they are exact in the output.

    Args:
        layout (TrajectoryLayout): window shapes.
        denoiser (nn.Module, optional): maps ``(z, t, mask)`` to ``v̂``; defaults to a
            :class:`ResidualMLPDenoiser`.

    Keyword Args:
        schedule (str): noise schedule name, see :data:`SCHEDULES`. Defaults to ``"cosine"``.
        num_steps (int): the number of sampling steps ``N`` this model is trained
            for (32 for a teacher, halved by each distillation round).
        normalizer (Normalizer, optional): fitted statistics; saved with the model.
        hidden (int): width of the default denoiser. Defaults to ``256``.
        depth (int): residual blocks of the default denoiser. Defaults to ``3``.

    Examples:
        >>> import torch
        >>> layout = TrajectoryLayout(obs_dim=2, action_dim=2, horizon=4)
        >>> model = TrajectoryDiffusion(layout, num_steps=8, hidden=32, depth=1)
        >>> cond, mask = layout.conditioned_window(torch.randn(3, 2))
        >>> sample = model.sample(cond, mask)
        >>> torch.equal(sample[:, 0, :2], cond[:, 0, :2])
        True
    """

    def __init__(
        self,
        layout: TrajectoryLayout,
        denoiser: nn.Module | None = None,
        *,
        schedule: str = "cosine",
        num_steps: int = 32,
        normalizer: Normalizer | None = None,
        hidden: int = 256,
        depth: int = 3,
    ) -> None:
        super().__init__()
        if num_steps < 1:
            raise ValueError(f"num_steps must be >= 1, got {num_steps}.")
        self.layout = layout
        self.denoiser = denoiser or ResidualMLPDenoiser(
            layout.window_shape, hidden=hidden, depth=depth
        )
        self.schedule = NoiseSchedule(schedule)
        self.normalizer = normalizer or Normalizer(layout.obs_dim, layout.action_dim)
        self.register_buffer("_num_steps", torch.tensor(num_steps))
        self._num_steps_value = int(num_steps)  # host copy: no device read per call
        self.register_load_state_dict_post_hook(_refresh_num_steps)

    @property
    def num_steps(self) -> int:
        """``N``, the number of sampling steps the model is trained for.

        Saved in the state dict; read from a host copy, so reading it never syncs a
        device.
        """
        return self._num_steps_value

    @num_steps.setter
    def num_steps(self, value: int) -> None:
        self._num_steps.fill_(value)
        self._num_steps_value = int(value)

    def reset_parameters_recursive(self) -> None:
        """Re-initialises every layer of the denoiser (TorchRL's loss-module protocol)."""
        for module in self.denoiser.modules():
            if module is not self.denoiser and hasattr(module, "reset_parameters"):
                module.reset_parameters()

    def normalized_window(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The clean window ``x_0`` ``[*B, H + 1, D]`` of raw states and actions, in model units.

        Raw ``[*B, H + 1, obs_dim]`` states and ``[*B, H + 1, action_dim]`` actions
        go through the model's :class:`~torchrl_dual.diffusion.Normalizer`, then the
        layout's packing.
        """
        norm = self.normalizer
        return self.layout.pack(
            norm.normalize_observation(observation), norm.normalize_action(action)
        )

    # ---------------------------------------------------------------- forward process
    def _scales(self, t: torch.Tensor, like: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        alpha, sigma = self.schedule(t.to(like.dtype))
        return alpha[..., None, None], sigma[..., None, None]

    def noise(self, x0: torch.Tensor, t: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """Forward noising ``z_t = α_t·x_0 + σ_t·ε``."""
        alpha, sigma = self._scales(t, x0)
        return alpha * x0 + sigma * eps

    def v_target(self, x0: torch.Tensor, t: torch.Tensor, eps: torch.Tensor) -> torch.Tensor:
        """Regression target ``v = α_t·ε − σ_t·x_0``."""
        alpha, sigma = self._scales(t, x0)
        return alpha * eps - sigma * x0

    # ---------------------------------------------------------------- prediction
    def predict(
        self, z: torch.Tensor, t: torch.Tensor, cond: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Denoises ``z`` at time ``t``; returns ``(x̂, ε̂, v̂)``.

        ``x̂`` holds the known entries of ``cond`` exactly.
        """
        z = torch.where(mask, cond, z)
        v = self.denoiser(z, t, mask)
        alpha, sigma = self._scales(t, z)
        x_hat = torch.where(mask, cond, alpha * z - sigma * v)
        eps_hat = sigma * z + alpha * v
        return x_hat, eps_hat, v

    def ddim_step(
        self,
        z: torch.Tensor,
        t: torch.Tensor,
        s: torch.Tensor,
        cond: torch.Tensor,
        mask: torch.Tensor,
    ) -> torch.Tensor:
        """Deterministic DDIM update ``z_t → z_s`` (``s < t``)."""
        x_hat, eps_hat, _ = self.predict(z, t, cond, mask)
        alpha_s, sigma_s = self._scales(s, z)
        return torch.where(mask, cond, alpha_s * x_hat + sigma_s * eps_hat)

    def ddpm_step(
        self,
        z: torch.Tensor,
        t: torch.Tensor,
        s: torch.Tensor,
        cond: torch.Tensor,
        mask: torch.Tensor,
        generator: torch.Generator | None = None,
        mean_shift: MeanShift | None = None,
    ) -> torch.Tensor:
        """Ancestral update: a draw from the posterior ``q(z_s | z_t, x = x̂)``.

        ``mean_shift(z, t, Σ)``, if given, is added to the posterior mean ``μ`` (``Σ`` the
        posterior variance): classifier guidance's ``μ + s·Σ·∇ log p(y | z_t)`` (Dhariwal &
        Nichol 2021, Alg. 1). The known entries stay exact either way.
        """
        x_hat, _, _ = self.predict(z, t, cond, mask)
        alpha_t, sigma_t = self._scales(t, z)
        alpha_s, sigma_s = self._scales(s, z)
        alpha_ts = alpha_t / alpha_s
        var_ts = (sigma_t**2 - alpha_ts**2 * sigma_s**2).clamp_min(0.0)
        mean = (alpha_ts * sigma_s**2 * z + alpha_s * var_ts * x_hat) / sigma_t**2
        variance = var_ts * sigma_s**2 / sigma_t**2
        if mean_shift is not None:
            mean = mean + mean_shift(torch.where(mask, cond, z), t, variance)
        noise = torch.randn(z.shape, generator=generator, device=z.device, dtype=z.dtype)
        return torch.where(mask, cond, mean + variance.sqrt() * noise)

    # ---------------------------------------------------------------- sampling
    def time_grid(self, num_steps: int, device=None) -> torch.Tensor:
        """Times ``1 = t_k > … > t_0 = 0`` of a ``num_steps``-step sampler."""
        if num_steps < 1 or self.num_steps % num_steps:
            raise ValueError(
                f"num_steps={num_steps} must be a positive divisor of the model's "
                f"N={self.num_steps}."
            )
        return torch.linspace(1.0, 0.0, num_steps + 1, device=device)

    def sample(
        self,
        cond: torch.Tensor,
        mask: torch.Tensor,
        *,
        num_steps: int | None = None,
        sampler: str = "ddim",
        generator: torch.Generator | None = None,
        noise: torch.Tensor | None = None,
        mean_shift: MeanShift | None = None,
    ) -> torch.Tensor:
        """Draws normalized windows ``τ ~ p_θ(τ | known entries)``.

        Args:
            cond (Tensor): ``[*B, L, D]`` window whose ``mask`` entries are known.
            mask (Tensor): ``[*B, L, D]`` (or broadcastable) boolean mask.

        Keyword Args:
            num_steps (int, optional): sampling steps; a divisor of ``N``. Defaults to ``N``.
            sampler (str): ``"ddim"`` (deterministic given the initial noise) or ``"ddpm"``.
            generator (torch.Generator, optional): source of the initial noise.
            noise (Tensor, optional): the initial ``z_1``; drawn when omitted.
            mean_shift (callable, optional): ``(z_t, t, Σ) -> Δμ`` added to each DDPM
                posterior mean (:meth:`ddpm_step`); needs ``sampler="ddpm"`` and more than
                one step. :func:`~torchrl_dual.diffusion.classifier_guidance` builds one.
        """
        if sampler not in SAMPLERS:
            raise ValueError(f"Unknown sampler {sampler!r}; choose one of {SAMPLERS}.")
        if cond.shape[-2:] != self.layout.window_shape:
            raise ValueError(
                f"cond must end with the window shape {self.layout.window_shape}, "
                f"got {tuple(cond.shape)}."
            )
        mask = mask.expand_as(cond)
        times = self.time_grid(
            self.num_steps if num_steps is None else num_steps, device=cond.device
        )
        if mean_shift is not None and (sampler != "ddpm" or len(times) == 2):
            raise ValueError(
                "mean_shift (guidance) shifts DDPM posterior means: it needs sampler='ddpm' "
                f"and num_steps > 1, got sampler={sampler!r} with {len(times) - 1} step(s)."
            )
        if noise is None:
            noise = torch.randn(cond.shape, generator=generator, device=cond.device)
        z = torch.where(mask, cond, noise.to(cond.dtype))
        batch = cond.shape[:-2]
        if len(times) == 2:  # one step (the distilled student): x̂(z_1), either sampler
            return self.predict(z, times[0].expand(batch), cond, mask)[0]
        for t, s in zip(times[:-1], times[1:], strict=True):
            t_b, s_b = t.expand(batch), s.expand(batch)
            if sampler == "ddim":
                z = self.ddim_step(z, t_b, s_b, cond, mask)
            elif float(s) > 0:
                z = self.ddpm_step(z, t_b, s_b, cond, mask, generator, mean_shift)
            else:
                z = self.predict(z, t_b, cond, mask)[0]
        return z


def _refresh_num_steps(module: TrajectoryDiffusion, incompatible_keys) -> None:
    """After ``load_state_dict``: the host copy of ``N`` from the loaded buffer."""
    module._num_steps_value = int(module._num_steps)
