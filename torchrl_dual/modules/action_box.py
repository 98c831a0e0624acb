"""The executed action of DUAL's Gaussian policy: a draw of ``N(μ(s), σ̄²)`` clamped to the box.

DUAL's actor is an *unbounded* Gaussian (Eq. 7, ``π_θ = N(τ_{a_0}, σ̄²)``), while the env
executes actions in a box. Critics are trained on in-box actions only (the data, and
target actions projected onto the box), so a Q network queried outside the box returns
an extrapolation; an actor that climbs ``Q(s, a)`` there (the ``sac`` weighting of Eq. 7,
the Cal-QL variant) runs away from the box, and its clamped actions end in a corner.
Everything that queries a critic at a draw of DUAL's policy therefore queries it at the
action the env would execute: :class:`ActionBox` for
:class:`~torchrl_dual.objectives.WeightedMAPActorLoss`, :class:`ClippedNormal` for
critic losses that sample the policy through TorchRL's ``get_dist`` (Cal-QL's penalty and
targets, SO2's targets).
"""

from __future__ import annotations

import torch
from torch import nn
from torchrl.data import Bounded, TensorSpec, Unbounded
from torchrl.modules.distributions import IndependentNormal


def box_bounds(action_spec: TensorSpec) -> tuple[torch.Tensor, torch.Tensor] | None:
    """``(low, high)`` of a ``Bounded`` spec, ``None`` for an ``Unbounded`` one.

    Raises:
        TypeError: for any other spec (a discrete action has no box to clamp to).
    """
    if isinstance(action_spec, Bounded):
        return action_spec.space.low, action_spec.space.high
    if isinstance(action_spec, Unbounded):
        return None
    raise TypeError(
        f"an action box needs a Bounded or Unbounded action spec, got "
        f"{type(action_spec).__name__}; pass the continuous spec the policy acts in."
    )


class ActionBox(nn.Module):
    """``a ↦ clamp(a, low, high)``: the action the env executes for a policy draw ``a``.

    The gradient is the identity inside the box and zero outside, so a loss that reads
    ``Q(s, ActionBox(a))`` never rewards leaving the box. An ``Unbounded`` spec gives the
    identity.

    Args:
        action_spec (Bounded or Unbounded): the env's action spec.

    Examples:
        >>> import torch
        >>> from torchrl.data import Bounded
        >>> box = ActionBox(Bounded(-1.0, 1.0, shape=(2,)))
        >>> box(torch.tensor([[0.5, 3.0], [-2.0, -0.25]]))
        tensor([[ 0.5000,  1.0000],
                [-1.0000, -0.2500]])
    """

    def __init__(self, action_spec: TensorSpec) -> None:
        super().__init__()
        bounds = box_bounds(action_spec)
        self.bounded = bounds is not None
        if bounds is not None:
            self.register_buffer("low", bounds[0].detach().clone())
            self.register_buffer("high", bounds[1].detach().clone())

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        if not self.bounded:
            return action
        return torch.clamp(action, self.low, self.high)


class ClippedNormal(IndependentNormal):
    """TorchRL's ``IndependentNormal`` whose draws are clamped to ``[low, high]``.

    The distribution of the executed action of an unbounded Gaussian policy, for critic
    losses that sample it through ``get_dist`` (``distribution_kwargs={"low": ...,
    "high": ...}`` of a ``ProbabilisticActor``). :meth:`rsample_and_log_prob` (what
    TorchRL's losses call) scores the Gaussian draw before the clamp, as ``TanhNormal``
    scores its pre-tanh draw: ``log N(u; μ, σ²)``, the density the actor's entropy term
    uses. :meth:`log_prob` of a given in-box value is the Gaussian density there (the
    clamp's point masses on the faces are not represented).

    Examples:
        >>> import torch
        >>> dist = ClippedNormal(torch.tensor([[0.0, 5.0]]), torch.ones(1, 2), low=-1.0, high=1.0)
        >>> action, log_prob = dist.rsample_and_log_prob()
        >>> bool(action.abs().max() <= 1.0), tuple(log_prob.shape)
        (True, (1,))
        >>> dist.deterministic_sample
        tensor([[0., 1.]])
    """

    def __init__(
        self,
        loc: torch.Tensor,
        scale: torch.Tensor,
        *,
        low: float | torch.Tensor = -1.0,
        high: float | torch.Tensor = 1.0,
        **kwargs,
    ) -> None:
        super().__init__(loc, scale, **kwargs)
        self.low = torch.as_tensor(low, dtype=loc.dtype, device=loc.device)
        self.high = torch.as_tensor(high, dtype=loc.dtype, device=loc.device)

    def _clamp(self, value: torch.Tensor) -> torch.Tensor:
        return torch.clamp(value, self.low, self.high)

    def sample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        return self._clamp(super().sample(sample_shape))

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        return self._clamp(super().rsample(sample_shape))

    def rsample_and_log_prob(
        self, sample_shape: torch.Size | tuple[int, ...] = ()
    ) -> tuple[torch.Tensor, torch.Tensor]:
        draw = super().rsample(sample_shape)
        return self._clamp(draw), super().log_prob(draw)

    @property
    def mode(self) -> torch.Tensor:
        return self._clamp(super().mode)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return self._clamp(self.mean)
