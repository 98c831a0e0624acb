"""Any network ending in ``nn.Linear`` as a last-layer actor ("IQL + LA")."""

from __future__ import annotations

import torch
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
    TensorDictSequential,
)
from torch import nn
from torchrl.modules import TanhNormal

from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor, TanhSquash


class LinearHeadActor(LastLayerActor):
    """Any network ending in ``nn.Linear`` as a Gaussian actor with a Laplace-ready head.

    Args:
        network (nn.Sequential): e.g. a TorchRL :class:`~torchrl.modules.MLP`; its last
            module must be an ``nn.Linear``. The first ``action_dim`` outputs are the
            mean action (the ``loc`` half when a ``NormalParamExtractor`` followed it).
        action_dim (int): action dimension.

    Keyword Args:
        init_std (float): initial ``σ̄``. Defaults to ``0.3``.
        squash (nn.Module, optional): applied to the mean, e.g. :class:`TanhSquash`
            (:meth:`from_actor` sets it for a ``TanhNormal`` actor). Defaults to ``None``.

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
        the last ``nn.Linear`` is the affine read-out. For a ``ProbabilisticActor`` with a
        ``TanhNormal`` distribution the actor also gets ``squash=TanhSquash(low, high)``
        (the distribution's box), so ``μ(s)`` is the ``TanhNormal``'s deterministic action
        ``tanh(loc)`` on the box, while the Laplace posterior stays over the pre-tanh
        ``loc`` head. Pass ``squash=None`` to keep the pre-tanh ``loc``.

        A network that ends ``nn.Linear → squash → AddStateIndependentNormalScale`` (CORL's
        and d3rlpy's IQL actor, ``N(c + r tanh(u), σ²)``: the recipe's ``gaussian`` IQL
        actor) keeps its squash module (shared) with ``noise_after_squash=True``: the
        Gaussian is on the squashed mean, so the posterior is a Gauss-Newton fit through
        the squash's Jacobian; ``σ̄`` is the actor's own until set (``log_std``).

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
            >>> actor.action_dim, actor.head is net[0][-1], type(actor.squash).__name__
            (2, True, 'TanhSquash')
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
        elif len(layers) > 2 and isinstance(layers[-1], AddStateIndependentNormalScale):
            *layers, squash, _ = layers  # [..., Linear, squash, state-independent σ]
            if not callable(getattr(squash, "derivative", None)):
                raise TypeError(
                    "LinearHeadActor.from_actor: the module before the state-independent "
                    f"scale must be a squash with a derivative() (TanhSquash), got "
                    f"{type(squash).__name__}."
                )
            kwargs.setdefault("squash", squash)
            kwargs.setdefault("noise_after_squash", True)
        if not layers or not isinstance(layers[-1], nn.Linear):
            raise TypeError(
                f"LinearHeadActor.from_actor found no final nn.Linear in {type(actor).__name__} "
                f"(its network ends with {type(layers[-1]).__name__ if layers else 'nothing'})."
            )
        if "squash" not in kwargs:
            kwargs["squash"] = _tanh_normal_squash(actor)
        out = layers[-1].out_features
        return cls(nn.Sequential(*layers), out // 2 if halves else out, **kwargs)

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        """The trunk's output ``φ(s)``, ``[*B, d]`` (the head's input)."""
        return self.trunk(observation)

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """The actions are the head's action rows: returns ``head_rows`` unchanged.

        Args:
            head_rows (Tensor): the head's action rows, ``[..., A]``.
            context (Tensor): unused.
        """
        return head_rows

    def readout_scale(self) -> torch.Tensor:
        """Ones, ``[A]``: the read-out is the identity."""
        return torch.ones(self.action_dim, device=self.head.weight.device)


def _tanh_normal_squash(actor: nn.Module) -> TanhSquash | None:
    """The ``TanhSquash`` of a ``TanhNormal`` probabilistic actor's box; ``None`` otherwise."""
    if not isinstance(actor, ProbabilisticTensorDictSequential):
        return None
    distribution = actor.module[-1]
    if not issubclass(getattr(distribution, "distribution_class", object), TanhNormal):
        return None
    options = distribution.distribution_kwargs
    if options.get("tanh_loc", False):
        raise ValueError(
            "LinearHeadActor.from_actor: a TanhNormal with tanh_loc=True squashes loc twice; "
            "build the actor with tanh_loc=False (the default)."
        )
    return TanhSquash(options.get("low", -1.0), options.get("high", 1.0))


def _flatten_sequential(module: nn.Module) -> list[nn.Module]:
    if not isinstance(module, nn.Sequential):
        return [module]
    return [layer for child in module.children() for layer in _flatten_sequential(child)]
