"""DUAL's actor: the distilled one-step planner as a last-layer actor (Eq. 5, Eq. 7)."""

from __future__ import annotations

import torch

from torchrl_dual.diffusion.model import TrajectoryDiffusion
from torchrl_dual.modules.last_layer import LATENTS, LastLayerActor
from torchrl_dual.modules.one_step_fold import OneStepFold
from torchrl_dual.modules.paired_trunk import PairedTrunk
from torchrl_dual.modules.planner_policy import PlannerSampler


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
        transition_model (TrajectoryDiffusion, optional): the transition model
            ``p(s'|s, a)`` of the shift signal (Eq. 10) when it should keep its own
            weights, typically a copy of the distilled student that the actor's
            fine-tuning leaves alone. It is frozen (``requires_grad=False``) and
            registered, so it follows ``.to()`` and is saved with the actor. Without it,
            :meth:`encode_with_transition` uses the actor's own weights (Alg. 1's
            ``p_θ``); with it, both queries still run as one batched pass
            (:class:`~torchrl_dual.modules.paired_trunk.PairedTrunk`).

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
        transition_model: TrajectoryDiffusion | None = None,
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
        self.transition_model = transition_model
        if transition_model is not None:
            self._check_transition_model(transition_model)
            transition_model.requires_grad_(False)
            self._transition_fold = OneStepFold(
                transition_model, self.sigma_1, self._next_state_slice
            )
            self._paired = PairedTrunk(model.denoiser, transition_model.denoiser)

    def _check_transition_model(self, transition_model: TrajectoryDiffusion) -> None:
        if transition_model is self.model:
            raise ValueError(
                "transition_model is the actor's own planner; omit it to share the weights."
            )
        if transition_model.num_steps != 1 or transition_model.layout != self.model.layout:
            raise ValueError(
                "transition_model must be a one-step planner with the actor's layout "
                f"{self.model.layout}, got num_steps={transition_model.num_steps} and "
                f"{transition_model.layout} (use a copy of the distilled student)."
            )
        _, sigma = transition_model.schedule(torch.ones(()))
        if abs(float(sigma) - self.sigma_1) > 1e-6:
            raise ValueError("transition_model must use the actor's noise schedule.")

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
        in one batched denoiser pass (Eq. 10's ``ŝ_t``).

        The transition query uses :attr:`transition_model`'s weights when it is set (the
        two trunks run stacked, :class:`~torchrl_dual.modules.paired_trunk.PairedTrunk`),
        else the actor's own (Algorithm 1 writes the same ``θ`` for ``π_θ`` and
        ``p(s'|s, a; θ)``). The transition window has the zero latent, so
        ``ŝ_t = −σ_1 · v̂(row 1, states)`` is the deterministic prediction of
        :class:`~torchrl_dual.modules.TransitionModel` for those weights.

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
        if self.transition_model is not None:
            return self._encode_with_own_transition_model(
                observation, previous_observation, previous_action
            )
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

    def _encode_with_own_transition_model(
        self,
        observation: torch.Tensor,
        previous_observation: torch.Tensor,
        previous_action: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`encode_with_transition` when the transition model has its own weights."""
        linear = torch.nn.functional.linear
        if not self._folded():  # autograd or sampled latents: two plain passes
            predicted = PlannerSampler(self.transition_model).predict_next_observation(
                previous_observation, previous_action, deterministic=True
            )
            return self.features(observation), observation, predicted
        w_state, _, const, _, _ = self._fold.tensors()
        t_state, t_action, t_const, w_next, b_next = self._transition_fold.tensors()
        policy = linear(observation, w_state, const[0])
        transition = linear(previous_observation, t_state, t_const[1])
        transition = transition + linear(previous_action, t_action)
        features = self._paired(torch.stack([policy, transition]))
        return features[0], observation, linear(features[1], w_next, b_next)
