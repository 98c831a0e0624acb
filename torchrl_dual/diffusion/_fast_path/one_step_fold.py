"""Inference-time constant folding of the one-step planner's input and read-out layers."""

from __future__ import annotations

import torch
from torch import Tensor

from torchrl_dual._versioned_cache import VersionedCache
from torchrl_dual.diffusion.model import TrajectoryDiffusion


class OneStepFold:
    r"""Folded first layer of the one-step planner for the zero-latent queries of the actor.

    The distilled student is always evaluated at ``t = 1``, and with the zero latent its
    window is zero except the known row 0. The first layer of the denoiser,
    ``input_layer([z, mask]) + time_embedding(t)``, then reduces to

    .. math::

        W_s \, s + W_a \, a + c_{\text{mask}}, \qquad
        W_s = W_{z, s_0} / \sigma_s ,\quad W_a = W_{z, a_0} / \sigma_a ,

    where ``c_mask = W_mask · mask + b + time_embedding(1) − W_s μ_s (− W_a μ_a)`` holds
    everything that does not depend on the input, with the normalizer ``(μ, σ)`` folded
    in. The state read-out of the transition query, ``μ_s + σ_s ⊙ (−σ_1 (W v + b))``,
    folds into one affine map too. The folded tensors are recomputed whenever one of the
    tensors they come from changes (an optimizer step, ``load_state_dict``, ``.to()``):
    see :class:`~torchrl_dual._versioned_cache.VersionedCache`.

    The result equals the general path to float rounding (the tests compare the two after
    optimizer steps, ``load_state_dict``, ``.to()`` and normalizer refits); it is only
    used without autograd, on the action path, which runs at every env step: there it
    saves the window construction, the mask and time features and two layers of
    normalisation.

    Args:
        model (TrajectoryDiffusion): the one-step planner (not registered as a submodule).
        sigma_1 (float): ``σ_1`` of the schedule at ``t = 1``.
        next_state_rows (slice): head outputs of ``τ_{s_1}``.
    """

    def __init__(self, model: TrajectoryDiffusion, sigma_1: float, next_state_rows: slice) -> None:
        self.model = model
        self.sigma_1 = sigma_1
        self.next_state_rows = next_state_rows
        denoiser = model.denoiser
        # The modules whose tensors the folded ones derive from. Modules keep their
        # identity through .to() / load_state_dict; their tensors are checked at every call.
        sources = (
            model.normalizer,
            denoiser.input_layer,
            *(m for m in denoiser.time_embedding.modules() if isinstance(m, torch.nn.Linear)),
            denoiser.head,
        )
        self._cache = VersionedCache(sources, self._fold)

    def tensors(self) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        """The folded weights ``(W_s [H, S], W_a [H, A], c [2, H], W_next [S, H], b_next [S])``.

        ``c[0]`` is for the policy query (``s_0`` known), ``c[1]`` for the
        transition query (``s_0, a_0``).
        """
        self.model.normalizer.check_fitted()
        return self._cache.get()

    def _fold(self) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
        layout, denoiser, norm = self.model.layout, self.model.denoiser, self.model.normalizer
        obs_dim, transition_dim = layout.obs_dim, layout.transition_dim
        weight, bias = denoiser.input_layer.weight, denoiser.input_layer.bias
        flat = weight.shape[1] // 2  # input = [flattened window, flattened mask]
        # made on the weights' device: under torch.compile this runs inside the graph, and
        # a host tensor copied in would break a CUDA graph's capture
        masks = torch.stack(
            [layout.condition_mask(c, device=weight.device) for c in ("s0", "s0_a0")]
        )
        masks = masks.flatten(1).to(dtype=weight.dtype)
        time = denoiser.time_embedding(torch.ones(1, device=weight.device, dtype=weight.dtype))
        w_state = weight[:, :obs_dim] / norm.obs_std
        w_action = weight[:, obs_dim:transition_dim] / norm.action_std
        const = masks @ weight[:, flat:].T + bias + time - w_state @ norm.obs_mean
        const[1] -= w_action @ norm.action_mean
        head_weight = denoiser.head.weight[self.next_state_rows]
        head_bias = denoiser.head.bias[self.next_state_rows]
        scale = -self.sigma_1 * norm.obs_std
        return (
            w_state,
            w_action,
            const,
            scale[:, None] * head_weight,
            norm.obs_mean + scale * head_bias,
        )
