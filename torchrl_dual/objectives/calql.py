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
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import dispatch
from tensordict.utils import NestedKey
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules.distributions.utils import rsample_and_log_prob
from torchrl.objectives.cql import CQLLoss
from torchrl.objectives.utils import distance_loss

from torchrl_dual._utils import read_loss_input
from torchrl_dual.objectives.ensemble_q import EnsembleMLP

PENALTY_LAYOUTS = ("calql", "torchrl")
"""How :class:`CalQLLoss` groups the sampled actions inside the logsumexp."""

_PARAMS = (
    "actor_network_params",
    "qvalue_network_params",
    "target_actor_network_params",
    "target_qvalue_network_params",
)
"""The functional parameter groups whose weak references TorchRL clears under compile."""


class CalQLLoss(CQLLoss):
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
        traces a ``super()`` property, which Dynamo cannot."""
        if self._calql_in_keys is None:
            keys = CQLLoss.in_keys.fget(self)
            bound = self.tensor_keys.mc_return
            self._calql_in_keys = keys if bound in keys else [*keys, bound]
        return self._calql_in_keys

    @property
    def out_keys(self) -> list[str]:
        if self._out_keys is None:
            self._out_keys = [*CQLLoss.out_keys.fget(self), "bound_rate"]
        return self._out_keys

    @out_keys.setter
    def out_keys(self, values):
        self._out_keys = values

    def _make_vmap(self) -> None:
        """TorchRL's vmapped Q calls, the ``(None, 0)`` one as :class:`EnsembleMLP` (the
        same numbers, a faster backward) when the Q network is a plain MLP."""
        super()._make_vmap()
        if not self.deactivate_vmap:
            self._vmap_qvalue_networkN0 = EnsembleMLP.of(
                self.qvalue_network, self._vmap_qvalue_networkN0
            )

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        super()._forward_value_estimator_keys(**kwargs)
        self._calql_in_keys = None  # renamed keys: recomputed on the next read

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``CQLLoss.forward`` in one pass (:meth:`critic_terms`, then the BC, actor and
        entropy losses) plus ``bound_rate``: the actor runs once on ``s`` (with gradient)
        and once on ``s'`` (without), where ``CQLLoss`` runs it five times, twice on
        ``num_random`` copies of the batch. The draws are ``CQLLoss.forward``'s, in its
        order; the BC and actor losses read two distributions built from the same
        parameters, as ``CQLLoss``'s two evaluations of the actor give."""
        keys = self.tensor_keys
        curr_params = self._dist_params(tensordict, grad=True)
        critic, td_error = self._critic_terms(tensordict, curr_params.detach())
        rate = tensordict.get(keys.bound_rate).detach()
        alpha = self._alpha
        # actor_bc_loss: a draw from π(·|s), the log-likelihood of the data action
        dist = self.actor_network.build_dist_from_params(curr_params)
        _, log_prob = rsample_and_log_prob(dist)
        bc = alpha * log_prob - dist.log_prob(tensordict.get(keys.action))
        loss_actor_bc = self._reduce_loss(bc, tensordict=tensordict)
        # actor_loss: SAC's α·log π(a|s) − min_i Q_i(s, a), a ∼ π(·|s), Q read detached
        action, log_prob = rsample_and_log_prob(
            self.actor_network.build_dist_from_params(curr_params)
        )
        td_q = tensordict.select(*self.qvalue_network.in_keys, strict=False)
        td_q.set(keys.action, action)
        td_q = self._vmap_qvalue_networkN0(td_q, self._cached_detach_qvalue_params)
        min_q = td_q.get(keys.state_action_value).min(0)[0].squeeze(-1)
        if log_prob.shape != min_q.shape:
            raise RuntimeError(f"Losses shape mismatch: {log_prob.shape} and {min_q.shape}")
        loss_actor = self._reduce_loss(alpha * log_prob - min_q, tensordict=tensordict)
        log_prob = log_prob.detach()
        loss_alpha, _ = self.alpha_loss({keys.log_prob: log_prob}, mask_tensordict=tensordict)
        tensordict.set(keys.priority, td_error.detach().max(0).values)
        out = {  # CQLLoss.forward's entries, in its order
            "loss_actor": loss_actor,
            "loss_actor_bc": loss_actor_bc,
            "loss_qvalue": critic["loss_qvalue"],
            "loss_cql": critic["loss_cql"],
            "loss_alpha": loss_alpha,
        }
        if self.with_lagrange:
            out["loss_alpha_prime"] = critic["loss_alpha_prime"].mean()
        entropy = -log_prob.mean()
        if self.reduction == "none":
            td_out = TensorDict(out, batch_size=tensordict.batch_size)
            if self.scalar_output_mode == "non_tensor":
                td_out.set_non_tensor("alpha", self._alpha)
                td_out.set_non_tensor("entropy", entropy)
            td_out.set("bound_rate", rate)
        else:
            td_out = TensorDict(
                {**out, "alpha": self._alpha, "entropy": entropy, "bound_rate": rate.mean()}
            )
        self._clear_weakrefs(tensordict, td_out, *_PARAMS)
        return td_out

    def critic_terms(self, tensordict: TensorDictBase) -> dict[str, Tensor]:
        """The critic's losses in one pass: ``loss_qvalue``, ``loss_cql`` and, with
        ``with_lagrange``, ``loss_alpha_prime``; the values (and gradients) of
        :meth:`q_loss`, :meth:`cql_loss` and :meth:`alpha_prime_loss` called in that order
        with the same seed, computed with the actor evaluated once on ``s`` and once on
        ``s'`` (its distribution parameters repeated for the ``num_random`` draws of the
        penalty; ``q_loss`` and ``cql_loss`` evaluate it three times, twice on
        ``num_random`` copies of the batch). Writes what those methods write into
        ``tensordict``."""
        return self._critic_terms(tensordict)[0]

    def _critic_terms(
        self, tensordict: TensorDictBase, curr_params: TensorDictBase | None = None
    ) -> tuple[dict[str, Tensor], Tensor]:
        """:meth:`critic_terms` and the TD errors ``[2, *B]``; ``curr_params``: the actor's
        distribution parameters at ``s``, detached (computed here if ``None``)."""
        next_params = self._dist_params(tensordict.get("next"), grad=False)
        if self.max_q_backup:  # CQLLoss's own target (num_random draws at s')
            loss_qvalue, metadata = self.q_loss(tensordict)
            td_error = metadata["td_error"]
        else:
            loss_qvalue, td_error = self._q_loss(tensordict, next_params)
        loss_cql, _ = self._cql_loss(tensordict, curr_params, next_params)
        terms = {"loss_qvalue": loss_qvalue, "loss_cql": loss_cql}
        if self.with_lagrange:
            terms["loss_alpha_prime"] = self.alpha_prime_loss(tensordict)[0]
        return terms, td_error

    def _dist_params(self, tensordict: TensorDictBase, grad: bool) -> TensorDictBase:
        """The actor's distribution parameters at ``tensordict``'s actor inputs (``[*B]``),
        with the gradient to its parameters or, as ``CQLLoss`` samples the penalty's and
        the target's actions, with its parameters' ``.data`` (autograd mode unchanged: an
        actor may take another path without it)."""
        data = tensordict.select(*self.actor_network.in_keys, strict=False)
        params = self.actor_network_params if grad else self.actor_network_params.data
        with (
            set_exploration_type(ExplorationType.RANDOM),
            params.to_module(self.actor_network, preserve_module_state=False),
        ):
            dist_params = self.actor_network.get_dist_params(data)
        return dist_params.select(*self.actor_network.dist_params_keys)

    def _q_loss(self, tensordict: TensorDictBase, next_params: TensorDictBase):
        """``CQLLoss.q_loss`` (deterministic or soft backup) with the target action drawn
        from ``next_params``, the actor's parameters at ``s'``: the loss and the TD errors."""
        keys = self.tensor_keys
        with set_exploration_type(ExplorationType.RANDOM):
            dist = self.actor_network.build_dist_from_params(next_params)
            next_action, next_log_prob = rsample_and_log_prob(dist)
        target_td = tensordict.clone(False)
        next_td = target_td.get("next").select(*self.qvalue_network.in_keys, strict=False)
        next_td.set(keys.action, next_action)
        next_td = self._vmap_qvalue_networkN0(next_td, self.target_qvalue_network_params.data)
        next_value = next_td.get(keys.state_action_value).min(0)[0]
        alpha = self._alpha  # read as CQLLoss.q_loss does (it clamps log α to its bounds)
        if not self.deterministic_backup:
            if next_value.shape[-next_log_prob.ndim :] != next_log_prob.shape:
                next_log_prob = next_log_prob.unsqueeze(-1)
            next_value = next_value - alpha * next_log_prob
        target_td.set(("next", self.value_estimator.tensor_keys.value), next_value)
        target = self.value_estimator.value_estimate(target_td).squeeze(-1)
        q_pred = self._vmap_qvalue_networkN0(
            tensordict.select(*self.qvalue_network.in_keys, strict=False),
            self.qvalue_network_params,
        ).get(keys.state_action_value)
        tensordict.set(keys.pred_q1, q_pred[0])
        tensordict.set(keys.pred_q2, q_pred[1])
        q_pred = q_pred.squeeze(-1)
        loss = distance_loss(q_pred, target.expand_as(q_pred), loss_function=self.loss_function)
        loss = self._reduce_loss(loss.sum(0), tensordict=tensordict)
        return loss, (q_pred - target).pow(2).detach()

    def _get_policy_actions(
        self,
        data: TensorDictBase,
        actor_params: TensorDictBase,
        num_actions: int = 10,
        dist_params: TensorDictBase | None = None,
    ) -> tuple[TensorDictBase, Tensor]:
        """``CQLLoss._get_policy_actions``: ``num_actions`` draws of ``π(·|s)`` per state of
        ``data``, the actor inputs repeated (``[*B[:-1], B[-1]·num_actions]``) with the
        actions and their log-probs (no gradient to the actor). The actor runs once on
        ``data`` (or its ``dist_params`` are given) and its distribution parameters are
        repeated, where ``CQLLoss`` runs it on the repeated inputs: the same numbers where
        the matrix products give each row the same result whatever the number of rows."""
        if actor_params is not self.actor_network_params:
            return super()._get_policy_actions(data, actor_params, num_actions=num_actions)
        if dist_params is None:
            dist_params = self._dist_params(data, grad=False)
        repeated = _repeat(data.select(*self.actor_network.in_keys, strict=False), num_actions)
        with set_exploration_type(ExplorationType.RANDOM):
            dist = self.actor_network.build_dist_from_params(_repeat(dist_params, num_actions))
            action, log_prob = rsample_and_log_prob(dist)
        return repeated.set(self.tensor_keys.action, action), log_prob

    def _policy_q(
        self,
        tensordict: TensorDictBase,
        num: int,
        curr_params: TensorDictBase | None,
        next_params: TensorDictBase | None,
    ) -> tuple[Tensor, ...]:
        """Q of the uniform, current-policy and next-policy actions: ``[2, B·num]`` each,
        plus the two ``[B·num]`` log-probs. Draws in ``CQLLoss.cql_loss``'s order;
        ``curr_params`` / ``next_params``: the actor's distribution parameters at ``s`` /
        ``s'`` if the caller has them."""
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
        self._clear_weakrefs(tensordict, *_PARAMS)
        return loss, {"bound_rate": rate.mean().detach()}

    def _alpha_prime(self) -> Tensor:
        """``α' = exp(log α')``, clipped at 1e6 as the references and ``CQLLoss`` do."""
        return self.log_alpha_prime.exp().clamp_max(1e6)

    def alpha_prime_loss(self, tensordict: TensorDictBase) -> tuple[Tensor, dict]:
        """The Lagrange multiplier's loss ``−½·α'·Σ_i (mean loss_cql_i − w·τ)`` on the
        penalties :meth:`cql_loss` wrote (detached: only ``log α'`` gets a gradient)."""
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


def _repeat(data: TensorDictBase, num: int) -> TensorDictBase:
    """Each transition of ``data`` ``num`` times in a row along its last batch dimension:
    ``CQLLoss._get_policy_actions``'s ``repeat_interleave``, as a view where one entry is
    (a parameter broadcast over the batch, e.g. a state-independent scale, stays
    broadcast, as the actor run on repeated inputs gives it: the kernels that read it then
    take the same path)."""
    dim = data.ndim - 1
    shape = [*data.batch_size[:-1], data.batch_size[-1] * num]

    def repeat(x: Tensor) -> Tensor:
        expanded = x.unsqueeze(dim + 1).expand(*x.shape[: dim + 1], num, *x.shape[dim + 1 :])
        return expanded.reshape(*shape, *x.shape[dim + 1 :])

    return data.apply(repeat, batch_size=shape)
