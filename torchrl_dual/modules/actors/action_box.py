"""The executed action of DUAL's Gaussian policy: a draw of ``N(μ(s), σ̄²)`` clamped to the box.

DUAL's actor is an *unbounded* Gaussian (Eq. 7, ``π_θ = N(τ_{a_0}, σ̄²)``), while the env
executes actions in a box. Critics are trained on in-box actions only (the data, and
target actions projected onto the box), so a Q network queried outside the box returns
an extrapolation; an actor that climbs ``Q(s, a)`` there (the ``sac`` weighting of Eq. 7,
the Cal-QL variant) runs away from the box, and its clamped actions end in a corner.
Everything that draws DUAL's policy for a critic therefore draws the action the env would
execute, a :class:`ClippedNormal` (a censored Gaussian), and scores it with that
distribution's log-likelihood: :class:`ActionBox` in
:class:`~torchrl_dual.objectives.WeightedMAPActorLoss`'s ``sac`` weighting, and the
``distribution_class`` of the policy view that critic losses sample through TorchRL's
``get_dist`` (Cal-QL's penalty and targets, SO2's targets).
"""

from __future__ import annotations

import torch
from torch import nn
from torchrl.data import Bounded, TensorSpec, Unbounded
from torchrl.modules.distributions import IndependentNormal


def box_bounds(action_spec: TensorSpec) -> tuple[torch.Tensor, torch.Tensor]:
    """``(low, high)`` of a ``Bounded`` spec; ``(-inf, inf)`` for an ``Unbounded`` one.

    Raises:
        TypeError: for any other spec (a discrete action has no box to clamp to).
    """
    if isinstance(action_spec, Bounded):
        return action_spec.space.low, action_spec.space.high
    if isinstance(action_spec, Unbounded):
        return torch.tensor(-torch.inf), torch.tensor(torch.inf)
    raise TypeError(
        f"an action box needs a Bounded or Unbounded action spec, got "
        f"{type(action_spec).__name__}; pass the continuous spec the policy acts in."
    )


class ActionBox(nn.Module):
    """The env's action box: clamps draws and gives the executed-action distribution.

    :meth:`forward` clamps a draw, :meth:`distribution` gives the executed-action
    distribution of ``N(loc, scale²)`` (a :class:`ClippedNormal`).

    The clamp's gradient is the identity inside the box and zero outside, so a loss that
    reads ``Q(s, clamp(a))`` never rewards leaving the box. An ``Unbounded`` spec gives the
    identity and a plain Gaussian.

    Args:
        action_spec (Bounded or Unbounded): the env's action spec.

    Examples:
        >>> import torch
        >>> from torchrl.data import Bounded
        >>> box = ActionBox(Bounded(-1.0, 1.0, shape=(2,)))
        >>> box(torch.tensor([[0.5, 3.0], [-2.0, -0.25]]))
        tensor([[ 0.5000,  1.0000],
                [-1.0000, -0.2500]])
        >>> box.distribution(torch.zeros(2), torch.ones(2)).log_prob(torch.tensor([1.0, 0.0]))
        tensor(-2.7600)
    """

    def __init__(self, action_spec: TensorSpec) -> None:
        super().__init__()
        low, high = box_bounds(action_spec)
        self.register_buffer("low", low.detach().clone())
        self.register_buffer("high", high.detach().clone())

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        """Clamps ``action`` to ``[low, high]`` (any shape broadcastable with the box).

        The gradient is the identity inside the box and zero outside.
        """
        return torch.clamp(action, self.low, self.high)

    def distribution(self, loc: torch.Tensor, scale: torch.Tensor) -> ClippedNormal:
        """``clamp(N(loc, scale²))`` on this box."""
        return ClippedNormal(loc, scale, low=self.low, high=self.high)


class ClippedNormal(IndependentNormal):
    """The executed action of an unbounded Gaussian policy, ``clamp(X, low, high)``.

    Per dimension, for ``X ∼ N(loc, scale²)``.

    A censored Gaussian: a density inside the box and point masses on its faces.
    :meth:`log_prob` is the log-likelihood of that mixed distribution, summed over the
    action dimensions: ``log N(a; μ, σ²)`` where ``low < a < high``, ``log P(X ≤ low)`` where
    ``a = low`` and ``log P(X ≥ high)`` where ``a = high``. Its expectation is the
    (negative) entropy the ``sac`` weighting's ``α·log π`` and the critics' targets use: a
    mean beyond a face makes the face's mass grow, and the score pulls it back (a clamp
    has no tanh Jacobian to do it). Draws are the clamped Gaussian draws, reparameterised
    (the pathwise gradient is zero on a clamped entry). ``low``/``high`` of ``∓inf`` give
    the plain Gaussian; ``mean`` and ``variance`` stay the Gaussian's (before the clamp),
    ``mode`` and ``deterministic_sample`` are clamped. Used as the ``distribution_class``
    of a ``ProbabilisticActor`` with ``distribution_kwargs={"low": ..., "high": ...}`` for
    critic losses that sample the policy through ``get_dist``.

    Examples:
        >>> import torch
        >>> dist = ClippedNormal(torch.tensor([[0.0, 5.0]]), torch.ones(1, 2), low=-1.0, high=1.0)
        >>> action = dist.rsample()
        >>> bool(action.abs().max() <= 1.0), tuple(dist.log_prob(action).shape)
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
        """A clamped Gaussian draw ``clamp(X, low, high)``, ``[*sample_shape, *batch, A]``."""
        return self._clamp(super().sample(sample_shape))

    def rsample(self, sample_shape: torch.Size | tuple[int, ...] = ()) -> torch.Tensor:
        """A reparameterised clamped draw (pathwise gradient zero on a clamped entry).

        Shape ``[*sample_shape, *batch, A]``.
        """
        return self._clamp(super().rsample(sample_shape))

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        """The censored Gaussian's log-likelihood of ``value``, summed over the action dims.

        Per dimension: ``log N(a; μ, σ²)`` inside the box, ``log P(X ≤ low)`` at ``a = low`` and
        ``log P(X ≥ high)`` at ``a = high``.

        Args:
            value (Tensor): actions in the box, ``[..., A]``.

        Returns:
            The log-likelihood, ``[...]``.
        """
        normal = self.base_dist
        z = (value - normal.loc) / normal.scale
        inside = normal.log_prob(value)
        below = torch.special.log_ndtr(z)  # log P(X ≤ low), read where value == low
        above = torch.special.log_ndtr(-z)  # log P(X ≥ high), read where value == high
        per_dim = torch.where(
            value >= self.high, above, torch.where(value <= self.low, below, inside)
        )
        return per_dim.sum(-1)

    @property
    def mode(self) -> torch.Tensor:
        """The clamped Gaussian mode, ``clamp(loc, low, high)``."""
        return self._clamp(super().mode)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """The clamped mean, ``clamp(loc, low, high)`` (TorchRL's deterministic action)."""
        return self._clamp(self.mean)
