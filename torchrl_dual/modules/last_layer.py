"""Actors whose mean action is an affine read-out of a final ``nn.Linear``.

The weighted MAP actor loss (Eq. 7), its last-layer Laplace approximation (Eq. 8)
and the ensemble policy (Eq. 9) all work on the split
``μ(s) = scale ⊙ (W φ(s) + b)[rows] + shift(s)``: a trunk ``φ``, a linear head
``(W, b)`` and a read-out that is affine in the head output. Three actors provide it:

* :class:`PlannerActor`, DUAL's actor: the distilled one-step planner, whose
  ``τ_{a_0} = α_1·z − σ_1·v̂`` is affine in the head output ``v̂``;
* :class:`LinearHeadActor`, any network ending in ``nn.Linear`` (for instance a
  TorchRL ``MLP`` actor), which turns IQL into "IQL + LA";
* :class:`~torchrl_dual.modules.DDPMLastStepActor` (its own module), TorchRL's
  multi-step ``DiffusionActor``, which turns Diff-QL into "Diff-QL w LA".
"""

from __future__ import annotations

import math

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule, TensorDictSequential
from torch import nn

from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.modules.one_step_fold import OneStepFold

LATENTS = ("zero", "sample")


class LastLayerActor(nn.Module):
    """Base class: a Gaussian actor ``N(μ(s), σ²)`` with a linear last layer.

    Subclasses define :meth:`features` (or :meth:`encode`), the attribute :attr:`head`
    (an ``nn.Linear``), the buffer ``head_rows`` (indices of the head outputs that form
    the action) and :meth:`readout`. The learnable per-dimension ``log_std`` (σ̄ of Eq. 7 and Eq. 9)
    lives here so that it is saved with the actor.
    """

    head: nn.Linear
    head_rows: torch.Tensor

    def __init__(
        self, action_dim: int, *, init_std: float = 0.3, min_std: float = 1e-3, max_std: float = 2.0
    ) -> None:
        super().__init__()
        if not min_std <= init_std <= max_std:
            raise ValueError(
                f"init_std={init_std} must lie in [min_std={min_std}, max_std={max_std}]."
            )
        self.action_dim = action_dim
        self.log_std = nn.Parameter(torch.full((action_dim,), math.log(init_std)))
        self.min_log_std, self.max_log_std = math.log(min_std), math.log(max_std)

    @property
    def std(self) -> torch.Tensor:
        """The clamped aleatoric standard deviation ``σ̄`` per action dimension."""
        return self.log_std.clamp(self.min_log_std, self.max_log_std).exp()

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        """The trunk output ``φ(s)``, ``[..., d]``."""
        return self.encode(observation)[0]

    def encode(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(φ(s), context)``: the trunk output and what :meth:`readout` needs besides
        the head output (the observation by default; the chain's ``x_1`` for a
        multi-step diffusion actor)."""
        if type(self).features is LastLayerActor.features:
            raise NotImplementedError(
                f"{type(self).__name__} must override features() or encode()."
            )
        return self.features(observation), observation

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """Maps the selected head outputs ``[..., A]`` to actions (affine), given the
        ``context`` returned by :meth:`encode`."""
        raise NotImplementedError

    def readout_scale(self) -> torch.Tensor:
        """``|∂ action / ∂ head output|`` per action dimension, ``[A]``."""
        raise NotImplementedError

    def _set_head_rows(self, start: int, stop: int) -> None:
        """Declares head outputs ``start:stop`` as the action rows (a contiguous block)."""
        self.register_buffer("head_rows", torch.arange(start, stop))
        self._head_slice = slice(start, stop)

    def head_parameters(self) -> tuple[torch.Tensor, torch.Tensor]:
        """The action rows ``(W[rows], b[rows])`` of the head, as views."""
        return self.head.weight[self._head_slice], self.head.bias[self._head_slice]

    def head_output(self, features: torch.Tensor) -> torch.Tensor:
        """The action rows of the head, ``[..., A]``."""
        return torch.nn.functional.linear(features, *self.head_parameters())

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        """The mean action ``μ(s)``."""
        features, context = self.encode(observation)
        return self.readout(self.head_output(features), context)


class PlannerActor(LastLayerActor):
    """DUAL's actor: ``μ(s) = τ_{a_0}`` of the distilled one-step planner (Eq. 5, Eq. 7).

    The one-step sampler maps ``z_1`` to ``x̂ = α_1·z_1 − σ_1·v̂(z_1 | s_0 = s)``; the
    action rows of ``v̂`` come from the denoiser's final ``nn.Linear``, so ``τ_{a_0}``
    is affine in that layer's weights and Eq. 8's Laplace is exact for it.

    Args:
        model (TrajectoryDiffusion): a one-step planner (``num_steps == 1``), typically
            the output of :func:`~torchrl_dual.training.progressive_distillation`.
            Training this actor fine-tunes the planner's weights.

    Keyword Args:
        latent (str): ``"zero"`` (default) feeds the mean latent ``z_1 = 0`` so ``μ(s)``
            is a deterministic function of the state, as the Gaussian policy of Eq. 7
            needs; ``"sample"`` draws ``z_1 ~ N(0, I)`` at every call.
        init_std (float): initial ``σ̄``. Defaults to ``0.3`` (normalised by nothing:
            raw action units).

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> actor = PlannerActor(model)
        >>> actor(torch.randn(7, 3)).shape
        torch.Size([7, 2])
    """

    def __init__(self, model: TrajectoryDiffusion, *, latent: str = "zero", **kwargs) -> None:
        if model.num_steps != 1:
            raise ValueError(
                f"PlannerActor needs a one-step planner, got num_steps={model.num_steps}; "
                "run progressive_distillation(...) down to final_steps=1 first."
            )
        if latent not in LATENTS:
            raise ValueError(f"Unknown latent {latent!r}; choose one of {LATENTS}.")
        layout = model.layout
        super().__init__(layout.action_dim, **kwargs)
        self.model = model
        self.latent = latent
        self.head = model.denoiser.head
        self._set_head_rows(layout.obs_dim, layout.transition_dim)  # a_0 of row 0
        # head outputs of τ_{s_1}: row 1 of the flattened window, its state entries
        self._next_state_slice = slice(
            layout.transition_dim, layout.transition_dim + layout.obs_dim
        )
        # masks of the shared pass: [policy query (s_0 known), transition query (s_0, a_0)]
        pair = torch.stack([layout.condition_mask("s0"), layout.condition_mask("s0_a0")])
        self.register_buffer("pair_mask", pair, persistent=False)
        alpha, sigma = model.schedule(torch.ones(()))
        if latent == "sample" and float(alpha) > 1e-6:
            raise ValueError(
                f"latent='sample' needs a schedule that ends in pure noise (α_1 = 0), but the "
                f"{model.schedule.kind!r} schedule has α_1 = {float(alpha):.2e}; use the cosine "
                "schedule or latent='zero'."
            )
        # With z_1 = 0, or α_1 = 0, τ_{a_0} = -σ_1·v̂: the latent never enters the read-out.
        self.sigma_1 = float(sigma)
        self._fold = OneStepFold(model, self.sigma_1, self._next_state_slice)

    def _folded(self) -> bool:
        """Inference with the zero latent: the first layer is folded (see OneStepFold)."""
        return self.latent == "zero" and not torch.is_grad_enabled()

    def _latent_window(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        layout, norm = self.model.layout, self.model.normalizer
        cond, mask = layout.conditioned_window(norm.normalize_observation(observation))
        if self.latent == "sample":
            cond = torch.where(mask, cond, torch.randn_like(cond))
        return cond, mask

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        if observation.shape[-1] != self.model.layout.obs_dim:
            raise ValueError(
                f"observation must end with dim {self.model.layout.obs_dim}, got "
                f"{tuple(observation.shape)}."
            )
        if self._folded():
            w_state, _, const, _, _ = self._fold.tensors()
            hidden = torch.nn.functional.linear(observation, w_state, const[0])
            return self.model.denoiser.trunk(hidden)
        z, mask = self._latent_window(observation)
        t = torch.ones(z.shape[:-2], device=z.device)
        return self.model.denoiser.features(z, t, mask)

    def encode_with_transition(
        self,
        observation: torch.Tensor,
        previous_observation: torch.Tensor,
        previous_action: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The policy query at ``s_t`` and the transition query at ``(s_{t-1}, a_{t-1})``
        in one denoiser pass (Algorithm 1 l. 12 uses the same ``θ`` for ``π_θ`` and
        ``p(s'|s, a; θ)``).

        The two windows are stacked on a new leading dim; the transition window has the
        zero latent, so ``ŝ_t = −σ_1 · v̂(row 1, states)`` is the deterministic prediction
        of :class:`~torchrl_dual.modules.TransitionModel` for the same weights.

        Returns:
            ``(φ(s_t), context, ŝ_t)`` with ``ŝ_t`` of shape ``[*B, obs_dim]`` in raw units.
        """
        layout, norm = self.model.layout, self.model.normalizer
        if observation.shape != previous_observation.shape:
            raise ValueError(
                f"previous_observation {tuple(previous_observation.shape)} must have the "
                f"shape of the observation {tuple(observation.shape)}."
            )
        obs_dim, batch = layout.obs_dim, observation.shape[:-1]
        previous_action = previous_action.to(observation.dtype)
        if self._folded():
            w_state, w_action, const, w_next, b_next = self._fold.tensors()
            hidden = torch.nn.functional.linear(
                torch.stack([observation, previous_observation]), w_state
            )
            hidden[1] += torch.nn.functional.linear(previous_action, w_action)
            hidden += const.view(2, *[1] * len(batch), -1)
            features = self.model.denoiser.trunk(hidden)
            predicted = torch.nn.functional.linear(features[1], w_next, b_next)
            return features[0], observation, predicted
        states = norm.normalize_observation(torch.stack([observation, previous_observation]))
        windows = observation.new_zeros(2, *batch, *layout.window_shape)
        windows[..., 0, :obs_dim] = states
        windows[1, ..., 0, obs_dim:] = norm.normalize_action(previous_action)
        masks = self.pair_mask.view(2, *[1] * len(batch), *layout.window_shape)
        if self.latent == "sample":
            noise = torch.randn_like(windows[0])
            windows[0] = torch.where(masks[0], windows[0], noise)
        masks = masks.expand_as(windows)
        features = self.model.denoiser.features(
            windows, windows.new_ones(windows.shape[:-2]), masks
        )
        rows = self._next_state_slice
        v_next = torch.nn.functional.linear(
            features[1], self.head.weight[rows], self.head.bias[rows]
        )
        return features[0], observation, norm.denormalize_observation(-self.sigma_1 * v_next)

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        norm = self.model.normalizer  # denormalize_action(-σ_1 · v̂) as one fused op
        return torch.addcmul(norm.action_mean, head_rows, norm.action_std, value=-self.sigma_1)

    def readout_scale(self) -> torch.Tensor:
        return self.sigma_1 * self.model.normalizer.action_std


class LinearHeadActor(LastLayerActor):
    """Any network ending in ``nn.Linear`` as a Gaussian actor with a Laplace-ready head.

    Args:
        network (nn.Sequential): e.g. a TorchRL :class:`~torchrl.modules.MLP`; its last
            module must be an ``nn.Linear``. The first ``action_dim`` outputs are the
            mean action (the ``loc`` half when a ``NormalParamExtractor`` followed it).
        action_dim (int): action dimension.

    Keyword Args:
        init_std (float): initial ``σ̄``. Defaults to ``0.3``.

    Examples:
        >>> import torch
        >>> from torchrl.modules import MLP
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=4, num_cells=[16, 16]), 2)
        >>> actor(torch.randn(5, 3)).shape
        torch.Size([5, 2])
    """

    def __init__(self, network: nn.Sequential, action_dim: int, **kwargs) -> None:
        super().__init__(action_dim, **kwargs)
        layers = list(network.children())
        if not layers or not isinstance(layers[-1], nn.Linear):
            raise TypeError(
                "LinearHeadActor needs an nn.Sequential whose last module is nn.Linear, got "
                f"{type(layers[-1]).__name__ if layers else 'an empty network'}."
            )
        if layers[-1].out_features < action_dim:
            raise ValueError(
                f"The last layer has {layers[-1].out_features} outputs, fewer than "
                f"action_dim={action_dim}."
            )
        self.trunk = nn.Sequential(*layers[:-1])
        self.head = layers[-1]
        self._set_head_rows(0, action_dim)

    @classmethod
    def from_actor(cls, actor: nn.Module, **kwargs) -> LinearHeadActor:
        """Wraps a TorchRL actor, sharing its weights ("IQL + LA" from an IQL actor).

        Unwraps ``ProbabilisticActor`` / ``TensorDictSequential`` (first module),
        ``Actor`` / ``TensorDictModule`` (``.module``) and nested ``nn.Sequential`` down to
        the layers; a trailing ``NormalParamExtractor`` is dropped and the ``loc`` half of
        the last ``nn.Linear`` becomes ``μ(s)`` (pre-squash for a ``TanhNormal`` actor).

        Examples:
            >>> import torch
            >>> from tensordict.nn import TensorDictModule
            >>> from torchrl.modules import MLP, NormalParamExtractor, ProbabilisticActor, TanhNormal
            >>> net = torch.nn.Sequential(MLP(in_features=3, out_features=4, num_cells=[16]),
            ...                           NormalParamExtractor())
            >>> iql_actor = ProbabilisticActor(
            ...     TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
            ...     in_keys=["loc", "scale"], distribution_class=TanhNormal)
            >>> actor = LinearHeadActor.from_actor(iql_actor)
            >>> actor.action_dim, actor.head is net[0][-1]
            (2, True)
        """
        network = actor
        while isinstance(network, (TensorDictSequential, TensorDictModule)):
            network = (
                network.module[0] if isinstance(network, TensorDictSequential) else (network.module)
            )
        layers = _flatten_sequential(network)
        halves = bool(layers) and isinstance(layers[-1], NormalParamExtractor)
        if halves:
            layers = layers[:-1]
        if not layers or not isinstance(layers[-1], nn.Linear):
            raise TypeError(
                f"LinearHeadActor.from_actor found no final nn.Linear in {type(actor).__name__} "
                f"(its network ends with {type(layers[-1]).__name__ if layers else 'nothing'})."
            )
        out = layers[-1].out_features
        return cls(nn.Sequential(*layers), out // 2 if halves else out, **kwargs)

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        return self.trunk(observation)

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        return head_rows

    def readout_scale(self) -> torch.Tensor:
        return torch.ones(self.action_dim, device=self.head.weight.device)


def _flatten_sequential(module: nn.Module) -> list[nn.Module]:
    if not isinstance(module, nn.Sequential):
        return [module]
    return [layer for child in module.children() for layer in _flatten_sequential(child)]
