"""DUAL's actor: the distilled planner as a last-layer actor (Eq. 5, Eq. 7).

One step (DUAL) or ``N`` DDIM steps (the "w/o distillation" ablation).
"""

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

    **N steps** (``model.num_steps = N > 1``, the paper's "w/o distillation" ablation):
    the first ``N − 1`` DDIM steps run with the current (MAP) weights from ``z_1`` to
    ``z_t`` (``t = 1/N``), and the last step's ``x̂ = α_t·z_t − σ_t·v̂(z_t)`` is read
    out: ``τ_{a_0}`` is again affine in the last step's final ``nn.Linear``, with
    ``α_t·z_t`` as the read-out's offset, so Eq. 8 is exact for the last step and the
    earlier steps are fixed features (as :class:`~torchrl_dual.modules.DDPMLastStepActor`
    does for TorchRL's ``DiffusionActor``). ``μ(s)`` then equals the deterministic
    ``N``-step :class:`~torchrl_dual.modules.PlannerSampler`'s ``a_0``. Training through
    it (Eq. 7) back-propagates through the whole chain.

    On the one-step action path (no autograd, zero latent) :meth:`features` and
    :meth:`encode_with_transition` take an exact constant-folded shortcut
    (``torchrl_dual.diffusion._fast_path``); with autograd or sampled latents they run
    the plain denoiser pass.

    Args:
        model (TrajectoryDiffusion): a planner sampled with its ``num_steps`` DDIM steps:
            one for DUAL, typically the output of
            :func:`~torchrl_dual.objectives.progressive_distillation`. Training this
            actor fine-tunes the planner's weights.

    Keyword Args:
        latent (str): ``"zero"`` (default) feeds the mean latent ``z_1 = 0`` so ``μ(s)``
            is a deterministic function of the state, as the Gaussian policy of Eq. 7
            needs; ``"sample"`` draws ``z_1 ~ N(0, I)`` at every call. Either way
            :meth:`sample_actions` draws the latent (the latent-UQ ablation).
        init_std (float): initial ``σ̄``. Defaults to ``0.3`` (normalised by nothing:
            raw action units).

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> observations, actions = torch.randn(64, 3), torch.rand(64, 2) * 2 - 1  # offline data
        >>> model = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=1, hidden=32, depth=1)
        >>> _ = model.normalizer.fit(observations, actions)
        >>> actor = PlannerActor(model)
        >>> actor(torch.randn(7, 3)).shape
        torch.Size([7, 2])
        >>> planner = TrajectoryDiffusion(TrajectoryLayout(3, 2, 4), num_steps=8, hidden=32, depth=1)
        >>> _ = planner.normalizer.fit(observations, actions)
        >>> eight = PlannerActor(planner)
        >>> eight(torch.randn(7, 3)).shape, eight.sample_actions(torch.randn(7, 3), 5).shape
        (torch.Size([7, 2]), torch.Size([5, 7, 2]))
    """

    def __init__(
        self,
        model: TrajectoryDiffusion,
        *,
        latent: str = "zero",
        **kwargs,
    ) -> None:
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
        alpha, _ = model.schedule(torch.ones(()))
        if latent == "sample" and float(alpha) > 1e-6:
            raise ValueError(
                f"latent='sample' needs a schedule that ends in pure noise (α_1 = 0), but the "
                f"{model.schedule.kind!r} schedule has α_1 = {float(alpha):.2e}; use the cosine "
                "schedule or latent='zero'."
            )
        # The last step reads x̂ = α_t·z_t − σ_t·v̂ at t = 1/N (t = 1 for one step).
        self.num_steps = model.num_steps
        self._times = [float(t) for t in model.time_grid(self.num_steps)]
        alpha_t, sigma_t = model.schedule(torch.tensor(self._times[-2]))
        self.alpha_last, self.sigma_last = float(alpha_t), float(sigma_t)
        # One step: with z_1 = 0, or α_1 = 0, τ_{a_0} = -σ_1·v̂ (the latent never enters
        # the read-out) and the exact constant-folded shortcut applies.
        self.sigma_1 = self.sigma_last
        self._fast = (
            OneStepFastPath(model, self.sigma_1, self._next_state_slice)
            if self.num_steps == 1
            else None
        )

    def _use_fast_path(self) -> bool:
        """One-step inference with the zero latent: the exact shortcut applies."""
        return self._fast is not None and self.latent == "zero" and not torch.is_grad_enabled()

    def _check_observation(self, observation: torch.Tensor) -> None:
        if observation.shape[-1] != self.model.layout.obs_dim:
            raise ValueError(
                f"observation must end with dim {self.model.layout.obs_dim}, got "
                f"{tuple(observation.shape)}."
            )

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        """The last denoising step's trunk output ``φ(z_t)``, ``[*B, d]``.

        Takes the exact fast path on the one-step, no-autograd, zero-latent action path.

        Args:
            observation (Tensor): ``s``, ``[*B, obs_dim]``, raw units.
        """
        self._check_observation(observation)
        if self._use_fast_path():
            return self._fast.features(observation)
        return self._encode_chain(observation, self.latent == "sample")[0]

    def encode(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The last step's trunk ``φ(z_t)`` and the read-out's ``context``.

        For ``N > 1`` the context is the read-out's offset ``α_t·z_t`` of the
        ``a_0`` entries (normalised units).
        """
        if self.num_steps == 1:
            return self.features(observation), observation
        self._check_observation(observation)
        return self._encode_chain(observation, self.latent == "sample")

    def _encode_chain(
        self, observation: torch.Tensor, sample: bool
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The plain path: ``N − 1`` DDIM steps, then the last step's trunk.

        Starts from ``z_1`` (zero or drawn); returns ``(φ(z_t), α_t·z_t[a_0])``.
        """
        model = self.model
        layout, norm = model.layout, model.normalizer
        cond, mask = layout.conditioned_window(norm.normalize_observation(observation))
        z = torch.where(mask, cond, torch.randn_like(cond)) if sample else cond
        batch = cond.shape[:-2]
        times = self._times
        for t, s in zip(times[:-2], times[1:-1], strict=True):
            t_b, s_b = (cond.new_full(batch, v) for v in (t, s))
            z = model.ddim_step(z, t_b, s_b, cond, mask)
        t_last = cond.new_full(batch, times[-2])
        features = model.denoiser.features(z, t_last, mask)
        return features, self.alpha_last * z[..., 0, layout.obs_dim :]

    def sample_actions(self, observation: torch.Tensor, num_samples: int) -> torch.Tensor:
        """``M`` actions through the ``N``-step chain, ``[M, *B, A]``.

        The actions come from ``M`` latents ``τ^N ~ N(0, I)`` through the current
        (MAP) weights: the paper's "τ^N sampling" ablation of the Laplace ensemble
        (Eq. 9).
        """
        self._check_observation(observation)
        observations = observation.expand(num_samples, *observation.shape)
        features, offset = self._encode_chain(observations, True)
        norm = self.model.normalizer  # the last step's x̂ = α_t·z_t − σ_t·v̂, any N
        offset = torch.addcmul(norm.action_mean, offset, norm.action_std)
        return torch.addcmul(
            offset, self.head_output(features), norm.action_std, value=-self.sigma_last
        )

    def encode_with_transition(
        self,
        observation: torch.Tensor,
        transition_model: TransitionModel,
        previous_observation: torch.Tensor,
        previous_action: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The policy query at ``s_t`` and ``transition_model``'s query at ``(s_{t-1}, a_{t-1})``.

        The latter gives Eq. 10's ``ŝ_t``, in raw units.

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
        """The ``a_0`` entries of the last step's ``x̂ = α_t·z_t − σ_t·v̂``, in raw action units.

        Args:
            head_rows (Tensor): ``v̂`` of the ``a_0`` entries, ``[..., A]`` (or ``[M, ..., A]``).
            context (Tensor): the offset ``α_t·z_t[a_0]`` (normalised units) for ``N > 1``;
                unused for one step (``z_1 = 0``).

        Returns:
            ``denormalize_action(offset − σ_t·v̂)``, shaped like ``head_rows``.
        """
        norm = self.model.normalizer  # denormalize_action(offset - σ_t · v̂) as fused ops
        if self.num_steps == 1:
            return torch.addcmul(norm.action_mean, head_rows, norm.action_std, value=-self.sigma_1)
        offset = torch.addcmul(norm.action_mean, context, norm.action_std)
        return torch.addcmul(offset, head_rows, norm.action_std, value=-self.sigma_last)

    def readout_scale(self) -> torch.Tensor:
        """``σ_t`` times the action's standard deviation, ``[A]``: ``|∂ action / ∂ v̂|``."""
        return self.sigma_last * self.model.normalizer.action_std
