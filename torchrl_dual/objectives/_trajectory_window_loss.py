"""Input parsing shared by the trajectory-diffusion losses."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.objectives.common import LossModule

from torchrl_dual._utils import check_finite, read_loss_input
from torchrl_dual.diffusion.model import TrajectoryDiffusion


def normalized_windows(
    model: TrajectoryDiffusion,
    tensordict: TensorDictBase,
    *,
    observation_key: NestedKey,
    action_key: NestedKey,
    mask_key: NestedKey,
    action_condition_prob: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Reads ``[B, H + 1]`` windows, checks them, returns ``(x_0, mask)`` normalized.

    Call it with the loss's parameters in ``model`` (``params.to_module(model)``), so that
    the normalizer's statistics are the ones a cast or device move carried. The windows
    must have the dtype of those statistics (no silent cast).

    The conditioning mask is read from ``mask_key`` when present; otherwise ``s_0``
    is always known and ``a_0`` is known with probability ``action_condition_prob``
    (one network then serves as policy ``p(τ | s_0)`` and as transition model
    ``p(τ | s_0, a_0)``).
    """
    layout = model.layout
    observation = read_loss_input(tensordict, observation_key, "observation")
    action = read_loss_input(tensordict, action_key, "action")
    dtype = model.normalizer.obs_mean.dtype
    for role, value, dim in (
        ("observation", observation, layout.obs_dim),
        ("action", action, layout.action_dim),
    ):
        expected = (layout.length, dim)
        if value.ndim < 3 or tuple(value.shape[-2:]) != expected:
            raise ValueError(
                f"{role} must have shape [batch, {expected[0]}, {expected[1]}] "
                f"(windows of H + 1 = {layout.length} steps, dim {dim}), got "
                f"{tuple(value.shape)}. Sample windows with WindowReplayBuffer."
            )
        if value.dtype != dtype:
            raise TypeError(
                f"{role} is {value.dtype} but the planner's weights are {dtype}: cast the "
                f"batch (batch.to({dtype})) or the loss (loss.to({value.dtype}))."
            )
        check_finite(value, role, "clean the data first.")
    x0 = model.normalized_window(observation, action)
    mask = tensordict.get(mask_key, default=None)
    if mask is None:
        batch = x0.shape[:-2]
        know_action = torch.rand(batch, device=x0.device) < action_condition_prob
        s0 = layout.condition_mask("s0", device=x0.device)
        a0 = layout.condition_mask("s0_a0", device=x0.device) & ~s0
        mask = s0 | (a0 & know_action[..., None, None])
    elif mask.dtype != torch.bool or mask.shape[-2:] != layout.window_shape:
        raise ValueError(
            f"{mask_key!r} must be a boolean mask ending with {layout.window_shape}, got "
            f"dtype {mask.dtype} and shape {tuple(mask.shape)}."
        )
    return x0, mask.expand_as(x0)


def masked_mean(error: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-window mean of ``error`` over the entries the model must generate."""
    free = (~mask).to(error.dtype)
    return (error * free).sum((-2, -1)) / free.sum((-2, -1)).clamp_min(1.0)


class TrajectoryWindowLoss(LossModule):
    """Shared keys and input parsing of the losses that read ``[B, H + 1]`` windows."""

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observation (NestedKey): states of the window, ``[B, H + 1, obs_dim]``.
                Defaults to ``"observation"``.
            action (NestedKey): actions of the window, ``[B, H + 1, action_dim]``.
                Defaults to ``"action"``.
            condition_mask (NestedKey): optional boolean mask of known entries,
                ``[B, H + 1, obs_dim + action_dim]``. Defaults to ``"condition_mask"``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        condition_mask: NestedKey = "condition_mask"

    default_keys = _AcceptedKeys
    action_condition_prob: float

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    @property
    def in_keys(self) -> list[NestedKey]:
        return [self.tensor_keys.observation, self.tensor_keys.action]

    def _windows(
        self, model: TrajectoryDiffusion, tensordict: TensorDictBase
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return normalized_windows(
            model,
            tensordict,
            observation_key=self.tensor_keys.observation,
            action_key=self.tensor_keys.action,
            mask_key=self.tensor_keys.condition_mask,
            action_condition_prob=self.action_condition_prob,
        )
