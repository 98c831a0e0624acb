"""Sampling the planner conditioned on the current state (and action), in raw units."""

from __future__ import annotations

import torch
from torch import nn

from torchrl_dual._utils import check_finite, is_deterministic
from torchrl_dual.diffusion.model import MeanShift, TrajectoryDiffusion


class PlannerSampler(nn.Module):
    """Samples ``τ ~ p_θ(τ | τ_{s_0} = s)`` and returns ``(τ_{a_0}, τ_{s_1})`` in raw units.

    Under ``ExplorationType.DETERMINISTIC`` (and ``MODE``/``MEAN``) the plan is the DDIM
    (probability-flow) image of the zero latent, whatever ``sampler`` says, so the same
    state always gives the same plan; otherwise the latent is drawn and ``sampler`` used.

    Args:
        model (TrajectoryDiffusion): trained (and possibly distilled) planner.

    Keyword Args:
        num_steps (int, optional): sampling steps (a divisor of ``model.num_steps``);
            defaults to ``model.num_steps``.
        sampler (str): ``"ddim"`` or ``"ddpm"``. Defaults to ``"ddim"``.
        action_low, action_high (float or Tensor, optional): bounds the action is
            clamped to (an env's action spec).

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 3), torch.rand(64, 2) * 2 - 1)
        >>> sampler = PlannerSampler(model, action_low=-1.0, action_high=1.0)
        >>> action, next_observation = sampler(torch.randn(5, 3))
        >>> action.shape, next_observation.shape, bool(action.abs().max() <= 1.0)
        (torch.Size([5, 2]), torch.Size([5, 3]), True)
        >>> sampler.plan(torch.randn(5, 3)).shape  # [B, H + 1, obs_dim + action_dim]
        torch.Size([5, 5, 5])
    """

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        num_steps: int | None = None,
        sampler: str = "ddim",
        action_low: float | torch.Tensor | None = None,
        action_high: float | torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        self.model = model
        self.num_steps = num_steps
        model.time_grid(model.num_steps if num_steps is None else num_steps)  # validate early
        self.sampler = sampler
        self.action_low = action_low
        self.action_high = action_high

    def normalized_window(
        self,
        observation: torch.Tensor,
        action: torch.Tensor | None = None,
        *,
        deterministic: bool | None = None,
        mean_shift: MeanShift | None = None,
    ) -> torch.Tensor:
        """The sampled window in normalized units, ``[*B, H + 1, obs_dim + action_dim]``.

        ``mean_shift`` guides a DDPM sampler (see :meth:`TrajectoryDiffusion.sample`).
        """
        layout, norm = self.model.layout, self.model.normalizer
        if observation.shape[-1] != layout.obs_dim:
            raise ValueError(
                f"observation must end with dim {layout.obs_dim} (the planner's obs_dim), "
                f"got shape {tuple(observation.shape)}."
            )
        check_finite(observation, "observation", "the planner cannot condition on it.")
        action_norm = None if action is None else norm.normalize_action(action)
        cond, mask = layout.conditioned_window(norm.normalize_observation(observation), action_norm)
        if deterministic is None:
            deterministic = is_deterministic()
        return self.model.sample(
            cond,
            mask,
            num_steps=self.num_steps,
            sampler="ddim" if deterministic else self.sampler,
            noise=cond if deterministic else None,  # known entries of cond, zeros elsewhere
            mean_shift=mean_shift,
        )

    def plan(
        self,
        observation: torch.Tensor,
        action: torch.Tensor | None = None,
        *,
        deterministic: bool | None = None,
        mean_shift: MeanShift | None = None,
    ) -> torch.Tensor:
        """A whole window in raw units, ``[*B, H + 1, obs_dim + action_dim]``.

        ``s_0`` (and ``a_0`` when given) are copied from the input, hence exact;
        ``mean_shift`` guides a DDPM sampler (see :meth:`TrajectoryDiffusion.sample`).
        """
        layout, norm = self.model.layout, self.model.normalizer
        window = self.normalized_window(
            observation, action, deterministic=deterministic, mean_shift=mean_shift
        )
        states = norm.denormalize_observation(layout.observations(window))
        actions = norm.denormalize_action(layout.actions(window))
        states[..., 0, :] = observation
        if action is not None:
            actions[..., 0, :] = action
        return torch.cat([states, actions], dim=-1)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The planned first action and next state, ``(τ_{a_0}, τ_{s_1})``, in raw units.

        Args:
            observation (Tensor): ``s``, ``[*B, obs_dim]``.

        Returns:
            ``τ_{a_0}`` ``[*B, action_dim]`` (clamped to the bounds) and ``τ_{s_1}``
            ``[*B, obs_dim]``.
        """
        layout, norm = self.model.layout, self.model.normalizer
        window = self.normalized_window(observation)
        action = norm.denormalize_action(window[..., 0, layout.obs_dim :])
        if self.action_low is not None or self.action_high is not None:
            action = action.clamp(self.action_low, self.action_high)
        return action, norm.denormalize_observation(window[..., 1, : layout.obs_dim])

    def predict_next_observation(
        self,
        observation: torch.Tensor,
        action: torch.Tensor,
        *,
        deterministic: bool | None = None,
    ) -> torch.Tensor:
        """The transition model ``ŝ_1 ~ p_θ(τ_{s_1} | τ_{s_0} = s, τ_{a_0} = a)``."""
        window = self.normalized_window(observation, action, deterministic=deterministic)
        return self.model.normalizer.denormalize_observation(
            window[..., 1, : self.model.layout.obs_dim]
        )
