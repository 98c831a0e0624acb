"""Actors whose mean action is an affine read-out of a final ``nn.Linear``.

The weighted MAP actor loss (Eq. 7), its last-layer Laplace approximation (Eq. 8)
and the ensemble policy (Eq. 9) all work on the split
``μ(s) = scale ⊙ (W φ(s) + b)[rows] + shift(s)``: a trunk ``φ``, a linear head
``(W, b)`` and a read-out that is affine in the head output. Three actors provide it:

* :class:`~torchrl_dual.modules.PlannerActor` (its own module), DUAL's actor: the distilled one-step planner, whose
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
