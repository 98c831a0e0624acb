"""Actors whose mean action is an affine read-out of a final ``nn.Linear``.

The weighted MAP actor loss (Eq. 7), its last-layer Laplace approximation (Eq. 8)
and the ensemble policy (Eq. 9) all work on the split
``μ(s) = scale ⊙ (W φ(s) + b)[rows] + shift(s)``: a trunk ``φ``, a linear head
``(W, b)`` and a read-out that is affine in the head output. Three actors provide it:

* :class:`~torchrl_dual.modules.PlannerActor`, DUAL's actor: the distilled one-step planner, whose
  ``τ_{a_0} = α_1·z − σ_1·v̂`` is affine in the head output ``v̂``;
* :class:`~torchrl_dual.modules.LinearHeadActor`, any network ending in ``nn.Linear`` (for instance a
  TorchRL ``MLP`` actor), which turns IQL into "IQL + LA";
* :class:`~torchrl_dual.modules.DDPMLastStepActor`, TorchRL's
  multi-step ``DiffusionActor``, which turns Diff-QL into "Diff-QL w LA".

An actor may also carry a fixed ``squash`` applied after the read-out, e.g.
:class:`TanhSquash` for a TorchRL ``TanhNormal`` actor, whose action is
``tanh(loc)`` mapped to the action box. The Laplace posterior (Eq. 8) stays over the
affine head *before* the squash, and each ensemble member (Eq. 9) is squashed before
the members are averaged.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import nn

if TYPE_CHECKING:
    from torchrl_dual.modules.planner.transition_model import TransitionModel


class TanhSquash(nn.Module):
    """``a = c + r ⊙ tanh(u)``, ``c = (high + low) / 2``, ``r = (high − low) / 2``.

    The map TorchRL's ``TanhNormal(loc, scale, low, high)`` applies to its Gaussian
    (its deterministic action is ``TanhSquash(low, high)(loc)``), used as the
    ``squash`` of a :class:`LastLayerActor` whose head gives the pre-tanh ``loc``.

    Args:
        low, high (float or Tensor): the action box. Default to ``-1`` and ``1``.

    Examples:
        >>> import torch
        >>> squash = TanhSquash(0.0, 1.0)
        >>> squash(torch.tensor([0.0, 100.0, -100.0]))
        tensor([0.5000, 1.0000, 0.0000])
    """

    def __init__(self, low: float | torch.Tensor = -1.0, high: float | torch.Tensor = 1.0) -> None:
        super().__init__()
        low = torch.as_tensor(low, dtype=torch.get_default_dtype())
        high = torch.as_tensor(high, dtype=torch.get_default_dtype())
        if not bool((high > low).all()):
            raise ValueError(f"TanhSquash needs high > low, got low={low}, high={high}.")
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_range", (high - low) / 2)

    def forward(self, pre_squash: torch.Tensor) -> torch.Tensor:
        """Squashes pre-tanh values into the box, ``c + r ⊙ tanh(u)`` (any shape ``[..., A]``)."""
        return torch.addcmul(self.center, self.half_range, torch.tanh(pre_squash))

    def derivative(self, pre_squash: torch.Tensor) -> torch.Tensor:
        """``∂a/∂u = r ⊙ (1 − tanh²(u))``, element-wise (the Jacobian's diagonal).

        Examples:
            >>> import torch
            >>> TanhSquash(0.0, 1.0).derivative(torch.zeros(2))
            tensor([0.5000, 0.5000])
        """
        return self.half_range * (1.0 - torch.tanh(pre_squash).square())


class LastLayerActor(nn.Module):
    """Base class: a Gaussian actor ``N(μ(s), σ²)`` with a linear last layer.

    Subclasses define :meth:`features` (or :meth:`encode`), the attribute :attr:`head`
    (an ``nn.Linear``), the buffer ``head_rows`` (indices of the head outputs that form
    the action) and :meth:`readout`. The learnable per-dimension ``log_std`` (σ̄ of Eq. 7 and Eq. 9)
    lives here so that it is saved with the actor.

    ``squash`` (an ``nn.Module``, e.g. :class:`TanhSquash`, or ``None``) maps the
    read-out to the action: ``μ(s) = squash(readout(...))`` (:meth:`act`). The head,
    :meth:`readout_scale` and the Laplace posterior fitted on them are in the
    pre-squash space; with a squash, ``σ̄`` is the noise std of the pre-squash
    Gaussian likelihood in the posterior (the linearisation of Eq. 8 is exact there:
    the read-out is affine in the head) and the aleatoric std of Eq. 9 in action space.
    With ``noise_after_squash=True`` the Gaussian is instead centred on the squashed
    mean, ``N(squash(u), σ̄²)`` (CORL's and d3rlpy's IQL actor): ``σ̄`` is in action
    units and the posterior takes the squash's Jacobian into its Gauss-Newton Hessian
    (the squash must then have a ``derivative``, as :class:`TanhSquash`).
    :class:`~torchrl_dual.objectives.WeightedMAPActorLoss` assumes no squash (its
    Gaussian is centred on :meth:`forward`); a squashed actor is trained by its own loss
    (IQL's advantage-weighted regression on the ``TanhNormal`` actor whose weights
    :meth:`LinearHeadActor.from_actor` shares).

    Args:
        action_dim (int): ``A``, the action's size.

    Keyword Args:
        init_std (float): initial ``σ̄``. Defaults to ``0.3``.
        min_std, max_std (float): bounds ``σ̄`` is clamped to. Default to ``1e-3`` and ``2.0``.
        squash (nn.Module, optional): maps the read-out to the action (see above).
        noise_after_squash (bool): centre the Gaussian on the squashed mean (see above).
            Defaults to ``False``.

    Examples:
        >>> import torch
        >>> from torch import nn
        >>> class LinearPolicy(LastLayerActor):  # μ(s) = W s + b: the trunk is the identity
        ...     def __init__(self):
        ...         super().__init__(action_dim=2)
        ...         self.head = nn.Linear(3, 2)
        ...         self._set_head_rows(0, 2)
        ...     def features(self, observation):
        ...         return observation
        ...     def readout(self, head_rows, context):
        ...         return head_rows
        ...     def readout_scale(self):
        ...         return torch.ones(self.action_dim)
        >>> actor, s = LinearPolicy(), torch.randn(4, 3)
        >>> torch.allclose(actor(s), actor.head(s)), actor.std.detach()
        (True, tensor([0.3000, 0.3000]))
    """

    head: nn.Linear
    head_rows: torch.Tensor

    def __init__(
        self,
        action_dim: int,
        *,
        init_std: float = 0.3,
        min_std: float = 1e-3,
        max_std: float = 2.0,
        squash: nn.Module | None = None,
        noise_after_squash: bool = False,
    ) -> None:
        super().__init__()
        if noise_after_squash and not callable(getattr(squash, "derivative", None)):
            raise ValueError(
                "noise_after_squash=True needs a squash with a derivative() (e.g. "
                f"TanhSquash), got {type(squash).__name__}."
            )
        if not min_std <= init_std <= max_std:
            raise ValueError(
                f"init_std={init_std} must lie in [min_std={min_std}, max_std={max_std}]."
            )
        self.action_dim = action_dim
        self.init_log_std = math.log(init_std)
        self.log_std = nn.Parameter(torch.full((action_dim,), self.init_log_std))
        self.min_log_std, self.max_log_std = math.log(min_std), math.log(max_std)
        self.squash = squash  # None: a plain attribute, no state_dict entry
        self.noise_after_squash = bool(noise_after_squash)

    def reset_parameters_recursive(self) -> None:
        """Re-initialises the trunk, the head and ``σ̄``, as TorchRL's modules do.

        Every submodule that has ``reset_parameters`` is reset, and ``σ̄`` is set
        back to ``init_std``.

        Examples:
            >>> import torch
            >>> from torchrl.modules import MLP
            >>> from torchrl_dual.modules import LinearHeadActor
            >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 2)
            >>> with torch.no_grad():
            ...     _ = actor.log_std.fill_(1.0)
            >>> actor.reset_parameters_recursive()
            >>> actor.std
            tensor([0.3000, 0.3000], grad_fn=<ExpBackward0>)
        """
        for module in self.modules():
            if module is not self and callable(getattr(module, "reset_parameters", None)):
                module.reset_parameters()
        with torch.no_grad():
            self.log_std.fill_(self.init_log_std)

    @property
    def std(self) -> torch.Tensor:
        """The clamped aleatoric standard deviation ``σ̄`` per action dimension."""
        return self.log_std.clamp(self.min_log_std, self.max_log_std).exp()

    def features(self, observation: torch.Tensor) -> torch.Tensor:
        """The trunk output ``φ(s)``, ``[..., d]``."""
        return self.encode(observation)[0]

    def encode(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The trunk output ``φ(s)`` and the ``context`` :meth:`readout` needs besides it.

        ``context`` is the observation by default; the chain's ``x_1`` for a
        multi-step diffusion actor.
        """
        if type(self).features is LastLayerActor.features:
            raise NotImplementedError(
                f"{type(self).__name__} must override features() or encode()."
            )
        return self.features(observation), observation

    def encode_with_transition(
        self,
        observation: torch.Tensor,
        transition_model: TransitionModel,
        previous_observation: torch.Tensor,
        previous_action: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """:meth:`encode` of ``s_t`` and the transition model's ``ŝ_t``, DUAL's two acting queries.

        ``ŝ_t`` is ``transition_model``'s prediction for ``(s_{t-1}, a_{t-1})``: the
        two queries of DUAL's acting step (Eq. 9-10).

        Two separate calls here; :class:`~torchrl_dual.modules.PlannerActor` answers both
        in one batched pass when the transition model is a planner of its own shape.

        Returns:
            ``(φ(s_t), context, ŝ_t)``.
        """
        features, context = self.encode(observation)
        return features, context, transition_model.predict(previous_observation, previous_action)

    def readout(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """Maps the selected head outputs ``[..., A]`` to actions (affine).

        ``context`` is what :meth:`encode` returned with the trunk output.
        """
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

    def act(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """The action of the head outputs ``head_rows``: :meth:`readout`, then the ``squash``.

        ``head_rows`` is ``[..., A]``, or ``[M, ..., A]`` for ``M`` members; without
        a ``squash`` the action is the read-out alone.
        """
        action = self.readout(head_rows, context)
        squash = self.squash
        return action if squash is None else squash(action)

    def mean_jacobian(self, head_rows: torch.Tensor, context: torch.Tensor) -> torch.Tensor:
        """``∂μ_j/∂u_j`` at the head outputs ``head_rows`` (``[..., A]``).

        The read-out scale times the squash's derivative there (the read-out scale
        alone without a squash).
        """
        scale = self.readout_scale()
        if self.squash is None:
            return scale.expand_as(head_rows)
        return scale * self.squash.derivative(self.readout(head_rows, context))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        """The mean action ``μ(s)``."""
        features, context = self.encode(observation)
        return self.act(self.head_output(features), context)
