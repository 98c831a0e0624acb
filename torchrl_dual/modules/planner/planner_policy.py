"""Policy extraction from the trajectory planner (Eq. 5)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey

from torchrl_dual._utils import read_key
from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.modules.planner.planner_sampler import PlannerSampler


class PlannerPolicy(TensorDictModuleBase):
    """The planner as a TorchRL policy: ``a ~ τ_{a_0}``, ``τ ~ p_θ(τ | τ_{s_0} = s)`` (Eq. 5).

    Reads the observation and writes the first planned action ``τ_{a_0}`` and the
    planned next state ``τ_{s_1}``. Wrapping the distilled one-step student gives
    DUAL's fast policy; wrapping the ``N``-step teacher gives the Diffuser-style
    baseline. The sampler is :attr:`module` (a :class:`PlannerSampler`).

    Args:
        model (TrajectoryDiffusion): the planner.

    Keyword Args:
        num_steps (int, optional): sampling steps. Defaults to ``model.num_steps``.
        sampler (str): ``"ddim"`` or ``"ddpm"``. Defaults to ``"ddim"``.
        observation_key (NestedKey): input key. Defaults to ``"observation"``.
        action_key (NestedKey): output action key. Defaults to ``"action"``.
        next_observation_key (NestedKey): output key of ``τ_{s_1}``.
            Defaults to ``"planned_next_observation"``.
        action_low, action_high (float or Tensor, optional): clamp bounds.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 3), torch.rand(64, 2) * 2 - 1)
        >>> policy = PlannerPolicy(model, action_low=-1.0, action_high=1.0)
        >>> td = policy(TensorDict({"observation": torch.randn(5, 3)}, batch_size=[5]))
        >>> td["action"].shape, td["planned_next_observation"].shape
        (torch.Size([5, 2]), torch.Size([5, 3]))
    """

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        num_steps: int | None = None,
        sampler: str = "ddim",
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        next_observation_key: NestedKey = "planned_next_observation",
        action_low: float | torch.Tensor | None = None,
        action_high: float | torch.Tensor | None = None,
    ) -> None:
        super().__init__()
        self.module = PlannerSampler(
            model,
            num_steps=num_steps,
            sampler=sampler,
            action_low=action_low,
            action_high=action_high,
        )
        self.in_keys = [observation_key]
        self.out_keys = [action_key, next_observation_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Plans from the observation and writes ``τ_{a_0}`` and ``τ_{s_1}`` (Eq. 5).

        Args:
            tensordict (TensorDictBase): holds the observation ``[*B, obs_dim]``.

        Returns:
            ``tensordict`` with the action ``[*B, action_dim]`` and the planned next observation
            ``[*B, obs_dim]``, raw units.
        """
        # Plain get/set: the outputs are written without TensorDictModule's generic
        # output handling, which costs as much as a one-step sample at batch 1.
        action, next_observation = self.module(read_key(tensordict, self.in_keys[0], "The planner"))
        tensordict.set(self.out_keys[0], action)
        tensordict.set(self.out_keys[1], next_observation)
        return tensordict
