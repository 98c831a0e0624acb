"""The trajectory window ``τ = (s_0, a_0, …, s_H, a_H)`` the planner diffuses.

The paper (Section 2.2) writes a trajectory as a two-row "image" of states and
actions. Here a window is a tensor of shape ``[..., H + 1, obs_dim + action_dim]``:
row ``i`` is ``(s_i, a_i)``. Conditioning (inpainting) is described by a boolean
mask of the same trailing shape whose ``True`` entries are known and kept exact.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

CONDITIONS = ("s0", "s0_a0")


@dataclass(frozen=True)
class TrajectoryLayout:
    """Shapes and index helpers of an ``H``-step window.

    Args:
        obs_dim (int): state dimension.
        action_dim (int): action dimension.
        horizon (int): ``H``; the window holds ``H + 1`` state-action rows.
            Defaults to ``8`` (the paper's choice, Appendix A).

    Examples:
        >>> layout = TrajectoryLayout(obs_dim=4, action_dim=2, horizon=8)
        >>> layout.window_shape
        (9, 6)
        >>> layout.condition_mask("s0_a0").sum().item()
        6
    """

    obs_dim: int
    action_dim: int
    horizon: int = 8

    def __post_init__(self) -> None:
        for name in ("obs_dim", "action_dim"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}.")
        if self.horizon < 1:
            raise ValueError(f"horizon must be >= 1 (the window needs s_1), got {self.horizon}.")

    @property
    def length(self) -> int:
        """Number of rows, ``H + 1``."""
        return self.horizon + 1

    @property
    def transition_dim(self) -> int:
        """Size of one row ``(s_i, a_i)``, ``D = obs_dim + action_dim``."""
        return self.obs_dim + self.action_dim

    @property
    def window_shape(self) -> tuple[int, int]:
        """Trailing shape of a window, ``(L, D) = (H + 1, obs_dim + action_dim)``."""
        return (self.length, self.transition_dim)

    def pack(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Stacks ``[..., L, obs_dim]`` and ``[..., L, action_dim]`` into a window."""
        return torch.cat([observation, action], dim=-1)

    def observations(self, window: torch.Tensor) -> torch.Tensor:
        """The states of a window: ``[..., L, D]`` -> ``[..., L, obs_dim]`` (a view)."""
        return window[..., : self.obs_dim]

    def actions(self, window: torch.Tensor) -> torch.Tensor:
        """The actions of a window: ``[..., L, D]`` -> ``[..., L, action_dim]`` (a view)."""
        return window[..., self.obs_dim :]

    def condition_mask(self, condition: str = "s0", device=None) -> torch.Tensor:
        """Boolean mask of the known entries: ``s_0`` or ``(s_0, a_0)``."""
        if condition not in CONDITIONS:
            raise ValueError(f"Unknown condition {condition!r}; choose one of {CONDITIONS}.")
        mask = torch.zeros(self.window_shape, dtype=torch.bool, device=device)
        mask[0, : self.obs_dim] = True
        if condition == "s0_a0":
            mask[0, self.obs_dim :] = True
        return mask

    def conditioned_window(
        self, observation: torch.Tensor, action: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A window holding ``s_0`` (and ``a_0``) in row 0 and zeros elsewhere, and its mask.

        Args:
            observation (Tensor): ``[*B, obs_dim]`` normalized ``s_0``.
            action (Tensor, optional): ``[*B, action_dim]`` normalized ``a_0``.
        """
        batch = observation.shape[:-1]
        window = observation.new_zeros(*batch, *self.window_shape)
        window[..., 0, : self.obs_dim] = observation
        condition = "s0"
        if action is not None:
            window[..., 0, self.obs_dim :] = action
            condition = "s0_a0"
        mask = self.condition_mask(condition, device=observation.device)
        return window, mask.expand(*batch, *self.window_shape)
