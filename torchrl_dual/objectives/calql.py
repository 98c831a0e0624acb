"""Cal-QL: TorchRL's CQL loss with the policy Q-values of its penalty bounded by MC returns.

Nakamoto et al., 2023, "Cal-QL: Calibrated Offline RL Pre-Training for Efficient Online
Fine-Tuning" (NeurIPS), Sec. 5 (the Cal-QL regulariser) and Alg. 1: CQL's conservative regulariser
``α·(E_{s∼D, a∼π}[Q(s, a)] − E_{s,a∼D}[Q(s, a)])`` becomes
``α·(E_{s∼D, a∼π}[max(Q(s, a), V^μ(s))] − E_{s,a∼D}[Q(s, a)])``, with ``V^μ(s)`` the
Monte-Carlo return-to-go of the data (:func:`torchrl_dual.data.monte_carlo_returns`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import dispatch
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.objectives.cql import CQLLoss

from torchrl_dual._utils import read_loss_input
from torchrl_dual.objectives._one_pass_cql import PARAMS, OnePassCQLLoss

PENALTY_LAYOUTS = ("calql", "torchrl")
"""How :class:`CalQLLoss` groups the sampled actions inside the logsumexp."""


class CalQLLoss(OnePassCQLLoss):
    """The Cal-QL critic loss (Nakamoto et al. 2023, Sec. 5 and Alg. 1), a TorchRL ``CQLLoss``.

    Everything but the conservative penalty is :class:`~torchrl.objectives.CQLLoss`: the
    twin-Q Bellman loss ``loss_qvalue``, the SAC actor, BC and entropy losses, the optional
    Lagrange multiplier. The penalty (``loss_cql``) is CQL's importance-sampled
    ``logsumexp`` over ``num_random`` uniform actions and ``num_random`` policy actions at
    ``s`` and at ``s'``, minus the Q-value of the data action, where Cal-QL bounds the
    policy Q-values from below by the data's Monte-Carlo return ``G(s)``
    (``tensor_keys.mc_return``):

    1. ``a_u ∼ U(-1, 1)``, ``a_π ∼ π(·|s)``, ``a'_π ∼ π(·|s')`` (``num_random`` each; the
       penalty reads the actor detached: its gradients reach the Q networks only);
    2. ``Q_π ← max(Q(s, a_π), G(s))`` and ``Q'_π ← max(Q(·, a'_π), G(s))``  (Cal-QL, Alg. 1);
    3. ``loss_cql = w·(T·logsumexp([Q(s, a_u) − log 0.5^d, Q_π − log π(a_π|s),
       Q'_π − log π(a'_π|s')] / T) − Q(s, a))`` per Q network, summed over the two, with
       ``w = min_q_weight`` and ``T = temperature``.

    **Lagrange form** (``with_lagrange=True``, ``lagrange_thresh=τ``; Cal-QL's AntMaze
    setting, τ = 0.8): as in the Cal-QL and CQL reference code, the penalty of each Q
    network becomes ``α'·(loss_cql_i − w·τ)`` with ``α' = exp(log α')`` read detached, and
    ``loss_alpha_prime = −½·α'·Σ_i (loss_cql_i − w·τ)`` with the penalties detached: its
    gradient reaches ``log α'`` only, which grows while the penalty exceeds ``w·τ``. TorchRL
    0.14.1's ``CQLLoss`` learns ``α'`` but never applies it to ``loss_cql`` and lets
    ``loss_alpha_prime``'s gradient reach the Q networks; this class replaces both
    (``tests/objectives/test_calql.py`` checks that TorchRL still does so). ``log α'``
    starts at ``log_alpha_prime_init`` (the references' 1.0; TorchRL's 0).

    ``penalty_layout`` picks the grouping of step 3. ``"calql"`` (default) follows the
    Cal-QL and CQL reference code: the ``3·num_random`` actions of one state in one
    logsumexp, the next-state policy actions evaluated at ``s`` (``Q(s, a'_π)``).
    ``"torchrl"`` reproduces TorchRL 0.14's ``CQLLoss.cql_loss``: one logsumexp over the
    three sources per draw (averaged over the ``num_random`` draws) and ``Q(s', a'_π)``;
    with ``G = -inf`` it returns ``CQLLoss``'s outputs (to float precision; tested). Both
    layouts give one penalty per transition (``reduction="none"``), where ``CQLLoss``
    broadcasts its ``cql_q1_loss`` to ``[B, B·num_random]`` (same mean).

    **One pass** (:class:`~torchrl_dual.objectives._one_pass_cql.OnePassCQLLoss`):
    :meth:`forward` and :meth:`critic_terms` (the critic's ``loss_qvalue``, ``loss_cql``
    and, in the Lagrange form, ``loss_alpha_prime``) run the actor once on ``s`` and once
    on ``s'`` and draw the penalty's policy actions from its repeated parameters, with
    ``CQLLoss``'s draws in its order: the values and gradients of ``q_loss``,
    ``cql_loss``, ``alpha_prime_loss`` and ``actor_loss`` computed TorchRL's way (bit for
    bit where the actor's matrix products give a row the same numbers in any batch, as at
    the recipe's sizes).

    The bound comes from the data, computed once per episode with the critic's discount:
    terminated and truncated episodes both stop the sum at their last step (no bootstrap of
    a time-limit tail, as Cal-QL's code does), and with sparse rewards an episode that never
    succeeds gets ``r_fail / (1 - γ)`` everywhere (Cal-QL's AntMaze / Adroit rule, see
    :mod:`torchrl_dual.data.mc_returns`). Transitions without a bound can carry ``-inf``,
    which turns Cal-QL back into CQL for them.

    Args:
        actor_network (ProbabilisticTensorDictSequential): the stochastic actor (actions in
            ``[-1, 1]``, as CQL's uniform proposal assumes).
        qvalue_network (TensorDictModule): ``Q(s, a)``, duplicated into two networks.

    Keyword Args:
        penalty_layout (str): one of :data:`PENALTY_LAYOUTS`. Defaults to ``"calql"``.
        log_alpha_prime_init (float): the initial ``log α'`` of the Lagrange form (unused
            without ``with_lagrange``). Defaults to 1.0 (Cal-QL's and CORL's code).
        loss_function (str): the Bellman loss of each Q network. Defaults to ``"l2"``, the
            squared error of the Cal-QL, CQL, CORL and d3rlpy code; TorchRL's ``CQLLoss``
            defaults to ``"smooth_l1"``, whose gradient is capped at 1 per transition: with
            AntMaze's ``10 r − 5`` rewards (``|Q|`` up to 500) the Q networks then move
            orders of magnitude slower than the references'.
        **kwargs: every other keyword argument of ``CQLLoss``: ``min_q_weight`` (CQL's
            ``α``, default 1.0), ``num_random`` (10), ``temperature`` (1.0),
            ``with_lagrange`` (False), ``lagrange_thresh``, ``alpha_init``, ``reduction`` ...

    The input needs CQLLoss's keys plus ``tensor_keys.mc_return`` (``[*B, 1]`` or ``[*B]``).
    The output has CQLLoss's entries plus ``bound_rate``, the fraction of policy Q-values
    the bound raised (Cal-QL logs it); ``bound_rate`` is also written per sample into the
    input, as CQLLoss writes its ``cql_q1_loss``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import TensorDictModule
        >>> from torch import nn
        >>> from torchrl.data import Bounded
        >>> from torchrl.modules import MLP, NormalParamExtractor, ProbabilisticActor, TanhNormal
        >>> from torchrl.modules import ValueOperator
        >>> _ = torch.manual_seed(0)
        >>> n_obs, n_act, batch = 3, 2, 4
        >>> spec = Bounded(-torch.ones(n_act), torch.ones(n_act), (n_act,))
        >>> actor = ProbabilisticActor(
        ...     TensorDictModule(nn.Sequential(nn.Linear(n_obs, 2 * n_act), NormalParamExtractor()),
        ...         in_keys=["observation"], out_keys=["loc", "scale"]),
        ...     in_keys=["loc", "scale"], spec=spec, distribution_class=TanhNormal)
        >>> qvalue = ValueOperator(MLP(in_features=n_obs + n_act, out_features=1, num_cells=[8]),
        ...     in_keys=["observation", "action"])
        >>> loss_fn = CalQLLoss(actor, qvalue, num_random=4, min_q_weight=5.0)
        >>> loss_fn.make_value_estimator(gamma=0.99)
        >>> data = TensorDict({
        ...     "observation": torch.randn(batch, n_obs), "action": spec.rand((batch,)),
        ...     "mc_return": torch.full((batch, 1), 3.0),
        ...     ("next", "observation"): torch.randn(batch, n_obs),
        ...     ("next", "reward"): torch.ones(batch, 1),
        ...     ("next", "done"): torch.zeros(batch, 1, dtype=torch.bool),
        ...     ("next", "terminated"): torch.zeros(batch, 1, dtype=torch.bool)}, [batch])
        >>> out = loss_fn(data)
        >>> float(out["bound_rate"])  # a fresh critic sits far below G = 3
        1.0
        >>> (out["loss_qvalue"] + out["loss_cql"]).backward()
    """

    @dataclass
    class _AcceptedKeys(CQLLoss._AcceptedKeys):
        """CQLLoss's keys plus Cal-QL's.

        Attributes:
            mc_return (NestedKey): the Monte-Carlo return-to-go ``G(s)`` of the transition,
                the lower bound of the policy Q-values. Defaults to ``"mc_return"``.
            bound_rate (NestedKey): written per sample: the fraction of its policy
                Q-values raised by the bound. Defaults to ``"bound_rate"``.
        """

        mc_return: NestedKey = "mc_return"
        bound_rate: NestedKey = "bound_rate"

    default_keys = _AcceptedKeys
    tensor_keys: _AcceptedKeys

    def __init__(
        self,
        actor_network,
        qvalue_network,
        *,
        penalty_layout: str = "calql",
        log_alpha_prime_init: float = 1.0,
        loss_function: str = "l2",
        **kwargs,
    ):
        if penalty_layout not in PENALTY_LAYOUTS:
            raise ValueError(
                f"penalty_layout={penalty_layout!r} is not one of {PENALTY_LAYOUTS}: 'calql' "
                "follows the Cal-QL reference code, 'torchrl' reproduces CQLLoss's grouping."
            )
        self._calql_in_keys = None
        super().__init__(actor_network, qvalue_network, loss_function=loss_function, **kwargs)
        self.penalty_layout = penalty_layout
        if self.with_lagrange:
            with torch.no_grad():
                self.log_alpha_prime.fill_(log_alpha_prime_init)
        self.in_keys, self.out_keys  # noqa: B018 (cached now: compiled calls only read them)

    @property
    def in_keys(self) -> list[NestedKey]:
        """CQLLoss's keys, then the bound, in a fixed order (CQLLoss's come from a set).

        Computed eagerly (here and in :meth:`set_keys`) and read back as a plain list, so
        that ``@dispatch`` reading them inside ``torch.compile(fullgraph=True)`` never
        traces a ``super()`` property, which Dynamo cannot.
        """
        if self._calql_in_keys is None:
            keys = CQLLoss.in_keys.fget(self)
            bound = self.tensor_keys.mc_return
            self._calql_in_keys = keys if bound in keys else [*keys, bound]
        return self._calql_in_keys

    @property
    def out_keys(self) -> list[str]:
        """``CQLLoss``'s outputs, then ``bound_rate`` (the share of bounded policy Q)."""
        if self._out_keys is None:
            self._out_keys = [*CQLLoss.out_keys.fget(self), "bound_rate"]
        return self._out_keys

    @out_keys.setter
    def out_keys(self, values):
        self._out_keys = values

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        super()._forward_value_estimator_keys(**kwargs)
        self._calql_in_keys = None  # renamed keys: recomputed on the next read

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``CQLLoss.forward``'s outputs plus ``bound_rate``.

        ``CQLLoss.forward``'s outputs (computed in one pass: :class:`OnePassCQLLoss`)
        plus ``bound_rate``.
        """
        out = super().forward(tensordict)
        rate = tensordict.get(self.tensor_keys.bound_rate).detach()
        out.set("bound_rate", rate if self.reduction == "none" else rate.mean())
        return out

    def _policy_q(
        self,
        tensordict: TensorDictBase,
        num: int,
        curr_params: TensorDictBase | None,
        next_params: TensorDictBase | None,
    ) -> tuple[Tensor, ...]:
        """Q of the penalty's uniform, current-policy and next-policy actions.

        Q of the uniform, current-policy and next-policy actions: ``[2, B·num]`` each,
        plus the two ``[B·num]`` log-probs. Draws in ``CQLLoss.cql_loss``'s order;
        ``curr_params`` / ``next_params``: the actor's distribution parameters at ``s`` /
        ``s'`` if the caller has them.
        """
        action_key = self.tensor_keys.action
        random_actions = tensordict.get(action_key).new_empty(
            (*tensordict.shape[:-1], tensordict.shape[-1] * num, tensordict[action_key].shape[-1])
        )
        random_actions.uniform_(-1, 1)
        curr_td, curr_log_pi = self._get_policy_actions(
            tensordict, self.actor_network_params, num_actions=num, dist_params=curr_params
        )
        next_td, next_log_pi = self._get_policy_actions(
            tensordict.get("next"), self.actor_network_params, num, dist_params=next_params
        )
        if self.penalty_layout == "calql":  # Q(s, a'_π), as in the Cal-QL / CQL code
            next_td = curr_td.clone(False).set(action_key, next_td.get(action_key))
        random_td = curr_td.clone(False).set(action_key, random_actions)
        q = [
            self._vmap_qvalue_networkN0(td, self.qvalue_network_params)
            .get(self.tensor_keys.state_action_value)
            .squeeze(-1)
            for td in (random_td, curr_td, next_td)
        ]
        return (*q, curr_log_pi.detach(), next_log_pi.detach())

    def cql_loss(self, tensordict: TensorDictBase) -> tuple[Tensor, dict]:
        """Cal-QL's penalty (steps 1-3 of the class docstring); needs :meth:`q_loss` first."""
        return self._cql_loss(tensordict)

    def _cql_loss(
        self,
        tensordict: TensorDictBase,
        curr_params: TensorDictBase | None = None,
        next_params: TensorDictBase | None = None,
    ) -> tuple[Tensor, dict]:
        """:meth:`cql_loss` on the actor's parameters at ``s`` and ``s'`` if given."""
        if tensordict.get(self.tensor_keys.pred_q1, None) is None:
            raise KeyError(
                f"cql_loss reads {self.tensor_keys.pred_q1!r}, which q_loss writes: call "
                "q_loss(tensordict) first (forward does)."
            )
        pred_q = torch.stack(
            [tensordict.get(self.tensor_keys.pred_q1), tensordict.get(self.tensor_keys.pred_q2)]
        ).squeeze(-1)  # [2, *B]
        bound = read_loss_input(tensordict, self.tensor_keys.mc_return, "mc_return")
        if bound.numel() != tensordict.numel():
            raise ValueError(
                f"{self.tensor_keys.mc_return!r} has shape {list(bound.shape)} for a batch of "
                f"{list(tensordict.shape)}; it must be [*B, 1] or [*B], one return per "
                "transition (torchrl_dual.data.monte_carlo_returns)."
            )
        num = self.num_random
        q_random, q_curr, q_next, curr_log_pi, next_log_pi = self._policy_q(
            tensordict, num, curr_params, next_params
        )
        bound = bound.reshape(*tensordict.shape).repeat_interleave(num, dim=-1).to(q_curr)
        raised = torch.stack([q_curr < bound, q_next < bound]).float()  # [2 kinds, 2 nets, .]
        q_curr = torch.maximum(q_curr, bound)  # Cal-QL, Alg. 1: max(Q, G(s))
        q_next = torch.maximum(q_next, bound)
        random_density = np.log(0.5 ** tensordict.get(self.tensor_keys.action).shape[-1])
        terms = torch.stack(
            [q_random - random_density, q_next - next_log_pi, q_curr - curr_log_pi], -1
        )  # [2, *B·num, 3]
        shape = (2, *tensordict.shape, num, 3)
        if self.penalty_layout == "calql":
            lse = torch.logsumexp(terms.reshape(*shape).flatten(-2) / self.temperature, -1)
        else:
            lse = torch.logsumexp(terms / self.temperature, -1).reshape(shape[:-1]).mean(-1)
        cql_q = (lse * self.temperature - pred_q) * self.min_q_weight  # [2, *B]
        tensordict.set(self.tensor_keys.cql_q1_loss, cql_q[0])
        tensordict.set(self.tensor_keys.cql_q2_loss, cql_q[1])
        rate = raised.reshape(4, *tensordict.shape, num).mean((0, -1))
        tensordict.set(self.tensor_keys.bound_rate, rate)
        if self.with_lagrange:  # α'·w·(diff − τ) per network, α' a constant here
            cql_q = self._alpha_prime().detach() * (
                cql_q - self.min_q_weight * self.target_action_gap
            )
        loss = self._reduce_loss(cql_q.sum(0), tensordict=tensordict)
        self._clear_weakrefs(tensordict, *PARAMS)
        return loss, {"bound_rate": rate.mean().detach()}

    @property
    def critic_out_keys(self) -> tuple[str, ...]:
        """The terms :meth:`critic_terms` returns (the critic protocol of ``DUALLoss``)."""
        return ("loss_qvalue", "loss_cql", *(("loss_alpha_prime",) if self.with_lagrange else ()))

    def critic_parameters(self) -> list[Tensor]:
        """What the critic's optimizer steps (the critic protocol of ``DUALLoss``).

        What the critic's optimizer steps: the Q networks and, in the Lagrange form,
        ``log α'`` (as Cal-QL's code, at the critic's learning rate); not the actor nor
        the entropy's ``log α``.
        """
        params = list(self.qvalue_network_params.values(True, True))
        return [*params, self.log_alpha_prime] if self.with_lagrange else params

    def _alpha_prime(self) -> Tensor:
        """``α' = exp(log α')``, clipped at 1e6 as the references and ``CQLLoss`` do."""
        return self.log_alpha_prime.exp().clamp_max(1e6)

    def alpha_prime_loss(self, tensordict: TensorDictBase) -> tuple[Tensor, dict]:
        """The Lagrange multiplier's loss (its gradient reaches ``log α'`` only).

        The Lagrange multiplier's loss ``−½·α'·Σ_i (mean loss_cql_i − w·τ)`` on the
        penalties :meth:`cql_loss` wrote (detached: only ``log α'`` gets a gradient).
        """
        penalties = [tensordict.get(key, None) for key in self._cql_keys()]
        if any(penalty is None for penalty in penalties):
            raise KeyError(
                "alpha_prime_loss reads the penalties cql_loss writes: call "
                "cql_loss(tensordict) first (forward does)."
            )
        gap = self.min_q_weight * self.target_action_gap
        excess = sum(penalty.detach().mean() - gap for penalty in penalties)
        return -0.5 * self._alpha_prime() * excess, {}

    def _cql_keys(self) -> tuple[NestedKey, NestedKey]:
        return self.tensor_keys.cql_q1_loss, self.tensor_keys.cql_q2_loss
