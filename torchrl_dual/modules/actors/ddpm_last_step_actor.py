"""TorchRL's multi-step ``DiffusionActor`` (Diff-QL's policy class) as a last-layer actor."""

from __future__ import annotations

import torch
from torch import nn

from torchrl_dual.diffusion.model import LATENTS
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor


class DDPMLastStepActor(LastLayerActor):
    r"""A TorchRL :class:`~torchrl.modules.DiffusionActor` made Laplace-ready: "Diff-QL w LA".

    The DDPM chain of the actor ends with the step ``t = 0`` (no noise):

    .. math::

        a = \frac{1}{\sqrt{\alpha_0}}\Big(x_1 - \frac{\beta_0}{\sqrt{1-\bar\alpha_0}}\,
            \hat\epsilon(x_1, s, 0)\Big), \qquad \hat\epsilon = W\,\phi(x_1, s, 0) + b ,

    so, with ``x_1`` (the chain up to step 1) held at the MAP weights, the action is affine
    in the score network's final ``nn.Linear`` ``(W, b)``: ``φ`` is the trunk at the last
    step, ``x_1`` the read-out's offset and ``β_0 / (√α_0 √(1 − ᾱ_0))`` its scale. The
    last-layer Laplace of Eq. (8) and the ensemble of Eq. (9) then treat the last
    denoising step exactly and the earlier steps as fixed features (a last-step
    linearisation: a sampled head changes ``ε̂`` at every step of the real chain, which
    this approximation ignores). Paper, Fig. 4(c): "Diff-QL w LA_π".

    The chain runs once per call, whatever the ensemble size; the ``M`` sampled heads
    act on its last step only.

    Args:
        actor: a :class:`~torchrl.modules.DiffusionActor` (or its ``module``, the DDPM
            sampler with ``score_network``, ``betas``, ``alphas``, ``alphas_cumprod``,
            ``num_steps`` and ``action_dim``). Its ``score_network`` must be an
            ``nn.Sequential`` ending in ``nn.Linear``; training the wrapped actor (e.g.
            with TorchRL's ``DiffusionBCLoss``) trains the same weights.

    Keyword Args:
        latent (str): ``"zero"`` (default) runs the chain from ``x_N = 0`` without noise,
            as the actor does under ``InteractionType.DETERMINISTIC``, so ``μ(s)`` is a
            function of the state as Eq. (7) needs; ``"sample"`` draws the chain's noise
            at every call (the diffusion policy's own randomness).
        init_std (float): initial ``σ̄`` of the Gaussian around ``μ(s)``. Defaults to ``0.3``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import DiffusionActor
        >>> from torchrl_dual.modules import LaplaceEnsembleActor
        >>> diffusion = DiffusionActor(action_dim=2, obs_dim=3, num_steps=10)
        >>> policy = LaplaceEnsembleActor(DDPMLastStepActor(diffusion), num_samples=5)
        >>> _ = policy.fit_laplace([TensorDict(observation=torch.randn(64, 3), batch_size=[64])])
        >>> out = policy(TensorDict(observation=torch.randn(4, 3), batch_size=[4]))
        >>> out["action"].shape, bool((out["epistemic_variance"] > 0).all())
        (torch.Size([4, 2]), True)
    """

    def __init__(self, actor: nn.Module, *, latent: str = "zero", **kwargs) -> None:
        sampler = getattr(actor, "module", actor)
        missing = [
            name
            for name in ("score_network", "betas", "alphas", "alphas_cumprod", "num_steps")
            if not hasattr(sampler, name)
        ]
        if missing:
            raise TypeError(
                "DDPMLastStepActor wraps torchrl.modules.DiffusionActor (or its DDPM module); "
                f"{type(actor).__name__} lacks {missing}."
            )
        network = sampler.score_network
        layers = list(network.children()) if isinstance(network, nn.Sequential) else []
        if not layers or not isinstance(layers[-1], nn.Linear):
            raise TypeError(
                "DDPMLastStepActor needs a score_network that is an nn.Sequential ending in "
                f"nn.Linear (the ε̂ head), got {type(network).__name__}."
            )
        if any(isinstance(p, nn.parameter.UninitializedParameter) for p in network.parameters()):
            raise ValueError(
                "The score network still has lazy (uninitialised) layers: pass obs_dim= to "
                "DiffusionActor, or run it once on an observation before wrapping it."
            )
        if latent not in LATENTS:
            raise ValueError(f"Unknown latent {latent!r}; choose one of {LATENTS}.")
        action_dim = layers[-1].out_features
        super().__init__(action_dim, **kwargs)
        self.sampler = sampler
        self.latent = latent
        self.trunk = nn.Sequential(*layers[:-1])  # shares the modules (and weights)
        self.head = layers[-1]
        self._set_head_rows(0, action_dim)

    def _coefficients(self, t: int, like: torch.Tensor) -> tuple[torch.Tensor, ...]:
        beta, alpha, alpha_bar = (
            getattr(self.sampler, name)[t].to(device=like.device, dtype=like.dtype)
            for name in ("betas", "alphas", "alphas_cumprod")
        )
        return beta, alpha, alpha_bar

    def encode(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The last step's trunk and its input, ``(φ(x_1, s, 0), x_1 / √α_0)``.

        The chain runs down to ``x_1`` with the MAP weights, then the trunk of the
        last step.
        """
        batch = observation.shape[:-1]
        sample = self.latent == "sample"
        x = observation.new_zeros(*batch, self.action_dim)
        if sample:
            x = torch.randn_like(x)
        for t in range(int(self.sampler.num_steps) - 1, 0, -1):
            step = observation.new_full((*batch, 1), float(t))
            epsilon = self.sampler.score_network(torch.cat([x, observation, step], dim=-1))
            beta, alpha, alpha_bar = self._coefficients(t, x)
            x = (x - beta / (1.0 - alpha_bar).sqrt() * epsilon) / alpha.sqrt()
            if sample:
                x = x + beta.sqrt() * torch.randn_like(x)
        last = torch.cat([x, observation, observation.new_zeros(*batch, 1)], dim=-1)
        _, alpha_0, _ = self._coefficients(0, x)
        return self.trunk(last), x / alpha_0.sqrt()

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """The last DDPM step's action ``x_1 / √α_0 − β_0 / (√α_0 √(1 − ᾱ_0)) ε̂``.

        Args:
            head_rows (Tensor): ``ε̂``, the head's action rows, ``[..., A]`` (or ``[M, ..., A]``).
            context (Tensor): the offset ``x_1 / √α_0`` from :meth:`encode`, ``[..., A]``.

        Returns:
            The action, shaped like ``head_rows``.
        """
        return context - self.readout_scale().to(head_rows.dtype) * head_rows

    def readout_scale(self) -> torch.Tensor:
        """``|∂ action / ∂ ε̂| = β_0 / (√α_0 √(1 − ᾱ_0))`` per action dimension, ``[A]``."""
        beta, alpha, alpha_bar = self._coefficients(0, self.head.weight)
        scale = beta / (alpha.sqrt() * (1.0 - alpha_bar).sqrt())
        return scale.expand(self.action_dim)
