"""Two residual-MLP denoiser trunks with different weights as one batched pass."""

from __future__ import annotations

import torch
from torch import Tensor, nn
from torch.nn import functional as F  # noqa: N812

from torchrl_dual._versioned_cache import VersionedCache
from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser


class PairedTrunk:
    r"""Runs the trunks of two same-architecture denoisers as one batched pass.

    Two :class:`~torchrl_dual.diffusion.denoiser.ResidualMLPDenoiser` of the same
    architecture, each on its own inputs.

    DUAL's shift signal (Eq. 10) needs, at every step, the actor's policy query for
    ``s_t`` and the transition model's query for ``(s_{t-1}, a_{t-1})``. When the
    transition model keeps the distilled offline weights while the actor is fine-tuned,
    the two queries go through different weights. Stacking the weights of every layer
    (``[2, out, in]``) turns both passes into one sequence of batched matrix products
    (``torch.baddbmm``), so the shift signal costs no second pass.

    The stacked weights are rebuilt only when a weight of either trunk changes
    (:class:`~torchrl_dual._versioned_cache.VersionedCache`); use this on
    inference paths (no autograd).

    Args:
        first, second (ResidualMLPDenoiser): the two denoisers (not registered here).

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion.denoiser import ResidualMLPDenoiser
        >>> a, b = ResidualMLPDenoiser((3, 4), hidden=16), ResidualMLPDenoiser((3, 4), hidden=16)
        >>> hidden = torch.randn(2, 5, 16)  # [which trunk, batch, hidden]
        >>> out = PairedTrunk(a, b)(hidden)
        >>> torch.allclose(out[1], b.trunk(hidden[1]), atol=1e-6)
        True
    """

    def __init__(self, first: ResidualMLPDenoiser, second: ResidualMLPDenoiser) -> None:
        if len(first.blocks) != len(second.blocks) or first.feature_dim != second.feature_dim:
            raise ValueError(
                "PairedTrunk needs two denoisers of the same width and depth, got "
                f"{first.feature_dim}x{len(first.blocks)} and "
                f"{second.feature_dim}x{len(second.blocks)}."
            )
        self.denoisers = (first, second)
        self._eps = first.trunk_layers()[1].eps
        # Modules keep their identity through .to() / load_state_dict (their tensors do
        # not): the layer lists are read once, the layers' tensors checked at every call.
        self._layers = [self._trunk_layers(denoiser) for denoiser in self.denoisers]
        self._cache = VersionedCache(
            [layer for layers in self._layers for layer in layers], self._stack
        )

    @staticmethod
    def _trunk_layers(denoiser: ResidualMLPDenoiser) -> list[nn.Module]:
        blocks, output_norm = denoiser.trunk_layers()
        return [layer for block in blocks for layer in block] + [output_norm]

    def _stack(self) -> list[Tensor]:
        """The stacked parameters of both trunks, per layer.

        LayerNorm scale and shift ``[2, 1, H]``; linear ``Wᵀ [2, in, out]`` and bias
        ``[2, 1, out]``.
        """
        stacked = []
        for pair in zip(*self._layers, strict=True):
            weights = torch.stack([layer.weight for layer in pair])
            biases = torch.stack([layer.bias for layer in pair]).unsqueeze(1)
            if isinstance(pair[0], nn.Linear):
                weights = weights.mT.contiguous()
            else:
                weights = weights.unsqueeze(1)
            stacked += (weights, biases)
        return stacked

    def __call__(self, hidden: Tensor) -> Tensor:
        """``hidden`` ``[2, *B, H]`` (first layer's outputs of each model) → features."""
        shape = hidden.shape
        h = hidden.reshape(2, -1, shape[-1])
        tensors = self._cache.get()
        eps = self._eps
        width = (shape[-1],)
        for i in range(len(self.denoisers[0].blocks)):
            ln_w, ln_b, w_1, b_1, w_2, b_2 = tensors[6 * i : 6 * i + 6]
            x = torch.addcmul(ln_b, F.layer_norm(h, width, eps=eps), ln_w)
            x = torch.baddbmm(b_2, F.silu(torch.baddbmm(b_1, x, w_1)), w_2)
            h = h + x
        ln_w, ln_b = tensors[-2:]
        h = F.silu(torch.addcmul(ln_b, F.layer_norm(h, width, eps=eps), ln_w))
        return h.reshape(shape)
