"""The one object behind which the one-step planner's inference fast path lives."""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn import functional as F  # noqa: N812

from torchrl_dual.diffusion._fast_path.one_step_fold import OneStepFold
from torchrl_dual.diffusion._fast_path.paired_trunk import PairedTrunk
from torchrl_dual.diffusion.model import TrajectoryDiffusion


class OneStepFastPath:
    r"""Exact, autograd-free shortcuts for the zero-latent queries of a one-step planner.

    DUAL acts with the distilled one-step planner at every env step, asking it two
    things: the policy query ``φ(s_t)`` (``s_0`` known) and the transition query
    ``ŝ_t`` for ``(s_{t-1}, a_{t-1})`` (``s_0, a_0`` known, Eq. 10). On the action path
    (no autograd, zero latent) three exact rewrites make both cheap:

    * :class:`~torchrl_dual.diffusion._fast_path.one_step_fold.OneStepFold` folds the
      ``t = 1`` time features, the masks and the normalizer into the first layer and the
      transition read-out into one affine map;
    * when the transition model shares the planner's weights, both queries run as one
      stacked pass through the trunk;
    * when it has its own weights (a frozen copy),
      :class:`~torchrl_dual.diffusion._fast_path.paired_trunk.PairedTrunk` runs the two
      trunks as one batched pass (stacked weights, ``baddbmm``).

    Every derived tensor is cached until a source tensor changes
    (:class:`~torchrl_dual._versioned_cache.VersionedCache`). The
    results equal the general path to float rounding; the tests compare every shortcut
    with the plain path of :class:`~torchrl_dual.modules.PlannerActor`.

    Args:
        model (TrajectoryDiffusion): the one-step planner (not registered here).
        sigma_1 (float): ``σ_1`` of its schedule at ``t = 1``.
        next_state_rows (slice): head outputs of ``τ_{s_1}`` (row 1, state entries).
    """

    def __init__(self, model: TrajectoryDiffusion, sigma_1: float, next_state_rows: slice) -> None:
        self.model = model
        self.sigma_1 = sigma_1
        self.next_state_rows = next_state_rows
        self._fold = OneStepFold(model, sigma_1, next_state_rows)
        # the transition planner last paired with, its fold and the paired trunks
        self._pair: tuple[TrajectoryDiffusion, OneStepFold, PairedTrunk] | None = None
        self._pairs_with_memo: tuple[TrajectoryDiffusion, int, bool] | None = None

    def pairs_with(self, transition: TrajectoryDiffusion) -> bool:
        """Whether ``transition``'s query can join the policy query in one pass.

        It can if it is the planner itself, or a one-step planner of the same
        layout, width, depth and ``σ_1``. The answer is remembered for the last
        planner asked (the action path asks at every step).
        """
        if transition is self.model:
            return True
        memo = self._pairs_with_memo
        if memo is None or memo[0] is not transition or memo[1] != transition.num_steps:
            memo = (transition, transition.num_steps, self._compatible(transition))
            self._pairs_with_memo = memo
        return memo[2]

    def _compatible(self, transition: TrajectoryDiffusion) -> bool:
        if transition.num_steps != 1 or transition.layout != self.model.layout:
            return False
        mine, theirs = self.model.denoiser, transition.denoiser
        if (mine.feature_dim, len(mine.blocks)) != (theirs.feature_dim, len(theirs.blocks)):
            return False
        return abs(transition.schedule.scales_at(1.0)[1] - self.sigma_1) <= 1e-6

    def features(self, observation: Tensor) -> Tensor:
        """``φ(s)`` of the policy query, ``[*B, hidden]``."""
        w_state, _, const, _, _ = self._fold.tensors()
        return self.model.denoiser.trunk(F.linear(observation, w_state, const[0]))

    def features_with_transition(
        self,
        observation: Tensor,
        transition: TrajectoryDiffusion,
        previous_observation: Tensor,
        previous_action: Tensor,
    ) -> tuple[Tensor, Tensor]:
        """The policy query ``φ(s_t)`` and ``transition``'s prediction ``ŝ_t``, in one pass.

        ``ŝ_t`` is predicted for ``(s_{t-1}, a_{t-1})``, in raw units; see
        :meth:`pairs_with`.
        """
        if transition is self.model:
            return self._shared(observation, previous_observation, previous_action)
        fold, paired = self._paired(transition)
        w_state, _, const, _, _ = self._fold.tensors()
        t_state, t_action, t_const, w_next, b_next = fold.tensors()
        policy = F.linear(observation, w_state, const[0])
        query = F.linear(previous_observation, t_state, t_const[1])
        query = query + F.linear(previous_action, t_action)
        features = paired(torch.stack([policy, query]))
        return features[0], F.linear(features[1], w_next, b_next)

    def _shared(
        self, observation: Tensor, previous_observation: Tensor, previous_action: Tensor
    ) -> tuple[Tensor, Tensor]:
        w_state, w_action, const, w_next, b_next = self._fold.tensors()
        batch = observation.shape[:-1]
        hidden = F.linear(torch.stack([observation, previous_observation]), w_state)
        hidden[1] += F.linear(previous_action, w_action)
        hidden += const.view(2, *[1] * len(batch), -1)
        features = self.model.denoiser.trunk(hidden)
        return features[0], F.linear(features[1], w_next, b_next)

    def _paired(self, transition: TrajectoryDiffusion) -> tuple[OneStepFold, PairedTrunk]:
        if self._pair is None or self._pair[0] is not transition:
            fold = OneStepFold(transition, self.sigma_1, self.next_state_rows)
            self._pair = (transition, fold, PairedTrunk(self.model.denoiser, transition.denoiser))
        return self._pair[1], self._pair[2]
