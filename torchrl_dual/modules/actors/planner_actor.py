"""DUAL's actor: the distilled one-step planner as a last-layer actor (Eq. 5, Eq. 7)."""

from __future__ import annotations

import torch

from torchrl_dual.diffusion._fast_path import OneStepFastPath
from torchrl_dual.diffusion.model import LATENTS, TrajectoryDiffusion
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.modules.planner.transition_model import TransitionModel


class PlannerActor(LastLayerActor):
    """DUAL's actor: ``μ(s) = τ_{a_0}`` of the distilled one-step planner (Eq. 5, Eq. 7).

    The one-step sampler maps ``z_1`` to ``x̂ = α_1·z_1 − σ_1·v̂(z_1 | s_0 = s)``; the
    action rows of ``v̂`` come from the denoiser's final ``nn.Linear``, so ``τ_{a_0}``
    is affine in that layer's weights and Eq. 8's Laplace is exact for it.

    On the action path (no autograd, zero latent) :meth:`features` and
    :meth:`encode_with_transition` take an exact constant-folded shortcut
    (``torchrl_dual.diffusion._fast_path``); with autograd or sampled latents they run
    the plain denoiser pass.

    Args:
        model (TrajectoryDiffusion): a one-step planner (``num_steps == 1``), typically
            the output of :func:`~torchrl_dual.objectives.progressive_distillation`.
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

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        latent: str = "zero",
        **kwargs,
    ) -> None:
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
        alpha, sigma = model.schedule(torch.ones(()))
        if latent == "sample" and float(alpha) > 1e-6:
            raise ValueError(
                f"latent='sample' needs a schedule that ends in pure noise (α_1 = 0), but the "
                f"{model.schedule.kind!r} schedule has α_1 = {float(alpha):.2e}; use the cosine "
                "schedule or latent='zero'."
            )
        # With z_1 = 0, or α_1 = 0, τ_{a_0} = -σ_1·v̂: the latent never enters the read-out.
        self.sigma_1 = float(sigma)
        self._fast = OneStepFastPath(model, self.sigma_1, self._next_state_slice)

    def _use_fast_path(self) -> bool:
        """Inference with the zero latent: the exact shortcut applies."""
        return self.latent == "zero" and not torch.is_grad_enabled()

    def _check_observation(self, observation: torch.Tensor) -> None:
        if observation.shape[-1] != self.model.layout.obs_dim:
            raise ValueError(
                f"observation must end with dim {self.model.layout.obs_dim}, got "
                f"{tuple(observation.shape)}."
            )

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        self._check_observation(observation)
        if self._use_fast_path():
            return self._fast.features(observation)
        layout, norm = self.model.layout, self.model.normalizer
        z, mask = layout.conditioned_window(norm.normalize_observation(observation))
        if self.latent == "sample":
            z = torch.where(mask, z, torch.randn_like(z))
        t = torch.ones(z.shape[:-2], device=z.device)
        return self.model.denoiser.features(z, t, mask)

    def encode_with_transition(
        self,
        observation: torch.Tensor,
        transition_model: TransitionModel,
        previous_observation: torch.Tensor,
        previous_action: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The policy query at ``s_t`` and ``transition_model``'s query at
        ``(s_{t-1}, a_{t-1})`` (Eq. 10's ``ŝ_t``, raw units).

        On the action path both run as one batched pass when the transition model is
        this actor's own planner (``TransitionModel(actor.model, frozen=False)``,
        Algorithm 1's single ``θ``) or a zero-latent one-step planner of the same shape
        (a frozen copy); otherwise as two passes.

        Returns:
            ``(φ(s_t), context, ŝ_t)`` with ``ŝ_t`` of shape ``[*B, obs_dim]``.
        """
        self._check_observation(observation)
        if observation.shape != previous_observation.shape:
            raise ValueError(
                f"previous_observation {tuple(previous_observation.shape)} must have the "
                f"shape of the observation {tuple(observation.shape)}."
            )
        previous_action = previous_action.to(observation.dtype)
        planner = transition_model.model
        if (
            self._use_fast_path()
            and transition_model.latent == "zero"
            and self._fast.pairs_with(planner)
        ):
            features, predicted = self._fast.features_with_transition(
                observation, planner, previous_observation, previous_action
            )
            return features, observation, predicted
        return super().encode_with_transition(
            observation, transition_model, previous_observation, previous_action
        )

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        norm = self.model.normalizer  # denormalize_action(-σ_1 · v̂) as one fused op
        return torch.addcmul(norm.action_mean, head_rows, norm.action_std, value=-self.sigma_1)

    def readout_scale(self) -> torch.Tensor:
        return self.sigma_1 * self.model.normalizer.action_std
