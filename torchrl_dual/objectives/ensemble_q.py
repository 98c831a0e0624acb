"""An ensemble of MLP Q networks without vmap's per-call overhead.

TorchRL's vmapped ensemble of MLP Q networks, evaluated with vmap's own kernels but a
faster backward of the one-output last layer.

TorchRL's losses evaluate their ``E`` stacked Q networks with ``torch.func.vmap`` over a
functional call of the module (``LossModule._vmap_qvalue_networkN0``). For a TorchRL
``MLP`` (``nn.Linear`` layers and activations on the concatenated inputs), vmap runs each
layer as ``matmul(h, Wᵀ) + b`` on ``[E, M, ·]`` tensors, one ``bmm`` per layer, and
autograd computes the one-output last layer's gradients as ``∂W = bmm(hᵀ, g)`` and
``∂h = bmm(g, W)`` with ``g`` of shape ``[E, M, 1]``: a matrix-vector product through the
transposed ``h`` and an outer product, which MKL runs far slower on a CPU than the same
sums as ``bmm(gᵀ, h)`` and the same products as ``g ⊙ W`` (at ``M = 2560``: 4.0 against
0.2 ms and 0.5 against 0.1 ms on the EPYC of docs/benchmarks.md).

:class:`EnsembleMLP` runs vmap's operations in vmap's order without its per-call
overhead, except that last layer's backward, which it computes as ``bmm(gᵀ, h)`` (the same
length-``M`` sums: equal wherever BLAS gives a dot product the same result in either
orientation, as MKL does) and ``g ⊙ W`` (each entry one product, as the ``K = 1`` ``bmm``
computes it). ``tests/objectives/test_ensemble_q.py`` compares values and gradients with
TorchRL's vmapped call bit for bit.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey
from torch import Tensor, nn
from torchrl.modules import MLP, ValueOperator

ELEMENTWISE = (nn.ReLU, nn.Tanh, nn.SiLU, nn.ELU, nn.GELU, nn.LeakyReLU)
"""Activations applied entry by entry (vmap runs them on the stacked tensor as is)."""


class _OneOutputLayer(torch.autograd.Function):
    """The one-output last layer ``bmm(h, Wᵀ)`` with the fast backward.

    ``bmm(h, Wᵀ)`` for ``h`` ``[E, M, K]`` and ``W`` ``[E, 1, K]`` with the fast backward
    of the module docstring.
    """

    @staticmethod
    def forward(ctx, h: Tensor, weight: Tensor) -> Tensor:
        ctx.save_for_backward(h, weight)
        return torch.bmm(h, weight.mT)

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor | None, Tensor | None]:
        h, weight = ctx.saved_tensors
        grad_h = grad * weight if ctx.needs_input_grad[0] else None
        grad_weight = torch.bmm(grad.mT, h) if ctx.needs_input_grad[1] else None
        return grad_h, grad_weight


class EnsembleMLP:
    """The ``E`` Q networks of stacked parameters in one call, as TorchRL's vmap gives them.

    ``(tensordict, params) -> tensordict``: the ``E`` Q networks of stacked ``params``
    (``[E]``, the layout of ``LossModule.convert_to_functional``) on a ``[M]`` batch,
    as TorchRL's ``_vmap_qvalue_networkN0`` gives them (``[E, M]``, the Q-values under the
    network's out key); other batch shapes go to ``fallback``, the vmapped call.

    Built by :meth:`of` for a ``ValueOperator`` whose module is a TorchRL ``MLP`` of
    ``nn.Linear`` layers and :data:`ELEMENTWISE` activations with one output.

    Examples:
        >>> import copy
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torch import nn
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives.utils import _vmap_func
        >>> q = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[8]),
        ...                   in_keys=["observation", "action"])
        >>> params = TensorDict.from_modules(q, copy.deepcopy(q), as_module=True)
        >>> vmapped = _vmap_func(q, (None, 0))
        >>> fast = EnsembleMLP.of(q, vmapped)
        >>> data = TensorDict(observation=torch.randn(5, 2), action=torch.rand(5, 1),
        ...                   batch_size=[5])
        >>> key = "state_action_value"
        >>> bool((fast(data, params)[key] == vmapped(data, params)[key]).all())
        True
    """

    def __init__(
        self,
        in_keys: list[NestedKey],
        out_key: NestedKey,
        layers: list[tuple[str, nn.Module, bool]],
        fallback: Callable[[TensorDictBase, TensorDictBase], TensorDictBase],
    ) -> None:
        self.in_keys, self.out_key, self.layers, self.fallback = in_keys, out_key, layers, fallback

    @classmethod
    def of(
        cls,
        qvalue_network: nn.Module,
        fallback: Callable[[TensorDictBase, TensorDictBase], TensorDictBase],
    ) -> EnsembleMLP | Callable[[TensorDictBase, TensorDictBase], TensorDictBase]:
        """The fast call for ``qvalue_network`` if it is such an MLP, else ``fallback``."""
        mlp = getattr(qvalue_network, "module", None)
        if not isinstance(qvalue_network, ValueOperator) or type(mlp) is not MLP:
            return fallback
        if mlp._reshape_out or len(qvalue_network.out_keys) != 1:
            return fallback
        layers = list(mlp.named_children())
        if not all(isinstance(m, (nn.Linear, *ELEMENTWISE)) for _, m in layers):
            return fallback
        if not isinstance(layers[-1][1], nn.Linear) or layers[-1][1].out_features != 1:
            return fallback
        layers = [(name, m, getattr(m, "bias", None) is not None) for name, m in layers]
        return cls(list(qvalue_network.in_keys), qvalue_network.out_keys[0], layers, fallback)

    def __call__(self, tensordict: TensorDictBase, params: TensorDictBase) -> TensorDictBase:
        """``Q_k(s, a)`` of every member ``k`` of ``params`` on a ``[M]`` batch.

        Returns a ``[E, M]`` tensordict holding the Q-values (TorchRL's vmapped call for
        other batch shapes).
        """
        if tensordict.ndim != 1:
            return self.fallback(tensordict, params)
        inputs = [tensordict.get(key) for key in self.in_keys]
        h = torch.cat(inputs, -1) if len(inputs) > 1 else inputs[0]
        weights = params.get("module")
        last = len(self.layers) - 1
        for i, (name, layer, bias) in enumerate(self.layers):
            if not isinstance(layer, nn.Linear):
                h = layer(h)
                continue
            weight = weights.get((name, "weight"))
            if i == last and h.ndim == 3:
                h = _OneOutputLayer.apply(h, weight)
            else:
                h = torch.matmul(h, weight.mT)
            if bias:
                h = h + weights.get((name, "bias")).unsqueeze(-2)
        return TensorDict({self.out_key: h}, batch_size=[h.shape[0], *tensordict.batch_size])


class EnsembleMLPCalls:
    """Mixin for a TorchRL loss with stacked Q networks: its vmapped Q call as :class:`EnsembleMLP`.

    Placed before the loss class (``class IQLCriticLoss(EnsembleMLPCalls, IQLLoss)``): after
    TorchRL's ``_make_vmap``, ``_vmap_qvalue_networkN0`` is :meth:`EnsembleMLP.of` of it when
    the Q networks are stacked (``[E]`` parameters) and a plain MLP, and stays TorchRL's
    otherwise (and with ``deactivate_vmap``). The same numbers and gradients, with less
    overhead per call and the faster last-layer backward of the module docstring.
    """

    def _make_vmap(self) -> None:
        super()._make_vmap()
        if not self.deactivate_vmap and self.qvalue_network_params.ndim == 1:
            self._vmap_qvalue_networkN0 = EnsembleMLP.of(
                self.qvalue_network, self._vmap_qvalue_networkN0
            )
