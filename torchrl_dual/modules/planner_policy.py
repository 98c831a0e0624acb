"""Policy extraction from the trajectory planner (Eq. 5) and its transition model."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torch import nn
from torchrl.envs.utils import ExplorationType, exploration_type

from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.modules._keys import read_key


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

    @staticmethod
    def _deterministic() -> bool:
        return exploration_type() in (
            ExplorationType.DETERMINISTIC,
            ExplorationType.MODE,
            ExplorationType.MEAN,
        )

    def normalized_window(
        self,
        observation: torch.Tensor,
        action: torch.Tensor | None = None,
        *,
        deterministic: bool | None = None,
    ) -> torch.Tensor:
        """The sampled window in normalized units, ``[*B, H + 1, obs_dim + action_dim]``."""
        layout, norm = self.model.layout, self.model.normalizer
        if observation.shape[-1] != layout.obs_dim:
            raise ValueError(
                f"observation must end with dim {layout.obs_dim} (the planner's obs_dim), "
                f"got shape {tuple(observation.shape)}."
            )
        if not torch.isfinite(observation).all():
            raise ValueError(
                "observation holds NaN/inf entries; the planner cannot condition on it."
            )
        action_norm = None if action is None else norm.normalize_action(action)
        cond, mask = layout.conditioned_window(norm.normalize_observation(observation), action_norm)
        if deterministic is None:
            deterministic = self._deterministic()
        return self.model.sample(
            cond,
            mask,
            num_steps=self.num_steps,
            sampler="ddim" if deterministic else self.sampler,
            noise=cond if deterministic else None,  # known entries of cond, zeros elsewhere
        )

    def plan(
        self,
        observation: torch.Tensor,
        action: torch.Tensor | None = None,
        *,
        deterministic: bool | None = None,
    ) -> torch.Tensor:
        """A whole window in raw units, ``[*B, H + 1, obs_dim + action_dim]``.

        ``s_0`` (and ``a_0`` when given) are copied from the input, hence exact.
        """
        layout, norm = self.model.layout, self.model.normalizer
        window = self.normalized_window(observation, action, deterministic=deterministic)
        states = norm.denormalize_observation(layout.observations(window))
        actions = norm.denormalize_action(layout.actions(window))
        states[..., 0, :] = observation
        if action is not None:
            actions[..., 0, :] = action
        return torch.cat([states, actions], dim=-1)

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
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
        # Plain get/set: the outputs are written without TensorDictModule's generic
        # output handling, which costs as much as a one-step sample at batch 1.
        action, next_observation = self.module(read_key(tensordict, self.in_keys[0], "The planner"))
        tensordict.set(self.out_keys[0], action)
        tensordict.set(self.out_keys[1], next_observation)
        return tensordict


class TransitionModel(TensorDictModuleBase):
    """``ŝ_1`` given ``(s_0, a_0)`` from the planner (Algorithm 1, line 5).

    The planner is trained with ``a_0`` sometimes known (see
    :class:`~torchrl_dual.objectives.DiffusionPlannerLoss`), so conditioning on
    both gives the transition model used by the shift signal of Eq. (10). By default
    (``latent="zero"``) the prediction is the DDIM image of the zero latent in every
    exploration mode, so ``d_t = ‖ŝ_t − s_t‖`` measures the shift and not the model's
    own sampling noise; ``latent="sample"`` draws it under random exploration.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> transition = TransitionModel(model)
        >>> td = TensorDict({"observation": torch.randn(5, 3), "action": torch.randn(5, 2)}, [5])
        >>> transition(td)["predicted_observation"].shape
        torch.Size([5, 3])
    """

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        num_steps: int | None = None,
        observation_key: NestedKey = "observation",
        action_key: NestedKey = "action",
        out_key: NestedKey = "predicted_observation",
        latent: str = "zero",
    ) -> None:
        super().__init__()
        if latent not in ("zero", "sample"):
            raise ValueError(f"Unknown latent {latent!r}; choose 'zero' or 'sample'.")
        self.sampler = PlannerSampler(model, num_steps=num_steps)
        self.deterministic = True if latent == "zero" else None
        self.in_keys = [observation_key, action_key]
        self.out_keys = [out_key]

    def predict(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Tensor-level call: ``ŝ_1`` for ``[*B, obs_dim]`` states and ``[*B, act_dim]`` actions."""
        return self.sampler.predict_next_observation(
            observation, action, deterministic=self.deterministic
        )

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        observation = read_key(tensordict, self.in_keys[0], "The planner")
        action = read_key(tensordict, self.in_keys[1], "The planner")
        tensordict.set(self.out_keys[0], self.predict(observation, action))
        return tensordict
