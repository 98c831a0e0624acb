"""TorchRL's CQL loss with the actor evaluated once per state (the base of Cal-QL's loss).

TorchRL 0.14's :class:`~torchrl.objectives.CQLLoss` runs the actor five times per
``forward``: on ``s'`` for the target action (``q_loss``), on ``num_random`` copies of
``s`` and of ``s'`` for the penalty's policy actions (``cql_loss``), and twice on ``s``
(``actor_bc_loss``, ``actor_loss``). :class:`OnePassCQLLoss` runs it once on ``s`` (with
gradient) and once on ``s'`` (with its parameters' ``.data``, as TorchRL), draws the
penalty's ``num_random`` actions per state from the distribution parameters repeated
(``CQLLoss`` draws the same noise from the actor run on the repeated states), and
evaluates the twin Q networks with :class:`~torchrl_dual.objectives.ensemble_q.EnsembleMLP`
where TorchRL's vmapped call would run. Every draw is ``CQLLoss``'s, in its order, so
the losses and gradients are TorchRL's bit for bit wherever the actor gives a state the
same numbers alone as in a larger batch (entry-wise operations always; MKL's matrix
products at the recipe's sizes), else to float rounding
(``tests/objectives/test_calql_one_pass.py``). On a CPU at 256 x 2 networks, batches of
256 and ``num_random = 10``, this is ``20·B`` rows of actor forward passes per update
(docs/benchmarks.md).
"""

from __future__ import annotations

from tensordict import TensorDict, TensorDictBase
from tensordict.nn import dispatch
from torch import Tensor
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules.distributions.utils import rsample_and_log_prob
from torchrl.objectives.cql import CQLLoss
from torchrl.objectives.utils import distance_loss

from torchrl_dual.objectives.ensemble_q import EnsembleMLPCalls

PARAMS = (
    "actor_network_params",
    "qvalue_network_params",
    "target_actor_network_params",
    "target_qvalue_network_params",
)
"""The functional parameter groups whose weak references TorchRL clears under compile."""


class OnePassCQLLoss(EnsembleMLPCalls, CQLLoss):
    """TorchRL's ``CQLLoss`` with the actor evaluated once per state.

    :class:`~torchrl.objectives.CQLLoss` whose :meth:`forward` and :meth:`critic_terms`
    evaluate the actor once per state (the module docstring); the subclass supplies the
    penalty, ``_cql_loss(tensordict, curr_params, next_params) -> (loss, metadata)``,
    which draws the penalty's policy actions with :meth:`_get_policy_actions` from the
    given distribution parameters. ``q_loss``, ``actor_loss``, ``actor_bc_loss`` and
    ``alpha_loss`` remain TorchRL's for callers that need one term (their Q calls are
    :class:`~torchrl_dual.objectives.ensemble_q.EnsembleMLP`'s).
    """

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``CQLLoss.forward`` in one pass.

        ``CQLLoss.forward`` in one pass: :meth:`critic_terms`, then the BC, actor and
        entropy losses on the actor's parameters at ``s`` computed once (two
        distributions built from them, as ``CQLLoss``'s two evaluations of the actor
        give). The same draws, in ``CQLLoss.forward``'s order; the same outputs.
        """
        keys = self.tensor_keys
        curr_params = self._dist_params(tensordict, grad=True)
        critic, td_error = self._critic_terms(tensordict, curr_params.detach())
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
        else:
            td_out = TensorDict({**out, "alpha": self._alpha, "entropy": entropy})
        self._clear_weakrefs(tensordict, td_out, *PARAMS)
        return td_out

    def critic_terms(self, tensordict: TensorDictBase) -> dict[str, Tensor]:
        """The critic's losses in one pass.

        The critic's losses in one pass: ``loss_qvalue``, ``loss_cql`` and, with
        ``with_lagrange``, ``loss_alpha_prime``; the values (and gradients) of
        :meth:`q_loss`, :meth:`cql_loss` and :meth:`alpha_prime_loss` called in that order
        with the same seed, computed with the actor evaluated once on ``s`` and once on
        ``s'`` (its distribution parameters repeated for the ``num_random`` draws of the
        penalty; ``q_loss`` and ``cql_loss`` evaluate it three times, twice on
        ``num_random`` copies of the batch). Writes what those methods write into
        ``tensordict``. The penalty is the subclass's ``_cql_loss(tensordict,
        curr_params, next_params)`` (its ``cql_loss`` on the actor's distribution
        parameters at ``s`` and ``s'``, detached).
        """
        return self._critic_terms(tensordict)[0]

    def _critic_terms(
        self, tensordict: TensorDictBase, curr_params: TensorDictBase | None = None
    ) -> tuple[dict[str, Tensor], Tensor]:
        """:meth:`critic_terms` and the TD errors ``[2, *B]``.

        :meth:`critic_terms` and the TD errors ``[2, *B]``; ``curr_params``: the actor's
        distribution parameters at ``s``, detached (computed here if ``None``).
        """
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
        """The actor's distribution parameters at the batch's actor inputs.

        The actor's distribution parameters at ``tensordict``'s actor inputs (``[*B]``),
        with the gradient to its parameters or, as ``CQLLoss`` samples the penalty's and
        the target's actions, with its parameters' ``.data`` (autograd mode unchanged: an
        actor may take another path without it).
        """
        data = tensordict.select(*self.actor_network.in_keys, strict=False)
        params = self.actor_network_params if grad else self.actor_network_params.data
        with (
            set_exploration_type(ExplorationType.RANDOM),
            params.to_module(self.actor_network, preserve_module_state=False),
        ):
            dist_params = self.actor_network.get_dist_params(data)
        return dist_params.select(*self.actor_network.dist_params_keys)

    def _q_loss(
        self, tensordict: TensorDictBase, next_params: TensorDictBase
    ) -> tuple[Tensor, Tensor]:
        """``CQLLoss.q_loss`` with the target action drawn from ``next_params``.

        ``CQLLoss.q_loss`` (deterministic or soft backup) with the target action drawn
        from ``next_params``, the actor's parameters at ``s'``: the loss and the TD errors.
        """
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
        """``num_actions`` draws of ``π(·|s)`` per state, as ``CQLLoss`` draws them.

        ``CQLLoss._get_policy_actions``: ``num_actions`` draws of ``π(·|s)`` per state of
        ``data``, the actor inputs repeated (``[*B[:-1], B[-1]·num_actions]``) with the
        actions and their log-probs (no gradient to the actor). The actor runs once on
        ``data`` (or its ``dist_params`` are given) and its distribution parameters are
        repeated, where ``CQLLoss`` runs it on the repeated inputs: the same numbers where
        the matrix products give each row the same result whatever the number of rows.
        """
        if actor_params is not self.actor_network_params:
            return super()._get_policy_actions(data, actor_params, num_actions=num_actions)
        if dist_params is None:
            dist_params = self._dist_params(data, grad=False)
        repeated = _repeat(data.select(*self.actor_network.in_keys, strict=False), num_actions)
        with set_exploration_type(ExplorationType.RANDOM):
            dist = self.actor_network.build_dist_from_params(_repeat(dist_params, num_actions))
            action, log_prob = rsample_and_log_prob(dist)
        return repeated.set(self.tensor_keys.action, action), log_prob


def _repeat(data: TensorDictBase, num: int) -> TensorDictBase:
    """Each transition of ``data`` repeated ``num`` times along its last batch dimension.

    Each transition of ``data`` ``num`` times in a row along its last batch dimension,
    ``CQLLoss._get_policy_actions``'s ``repeat_interleave``; an entry broadcast over the
    batch (a state-independent scale) stays a broadcast view, as the actor run on
    repeated inputs gives it, so the kernels reading it take the same path.
    """
    dim = data.ndim - 1
    shape = [*data.batch_size[:-1], data.batch_size[-1] * num]

    def repeat(x: Tensor) -> Tensor:
        expanded = x.unsqueeze(dim + 1).expand(*x.shape[: dim + 1], num, *x.shape[dim + 1 :])
        return expanded.reshape(*shape, *x.shape[dim + 1 :])

    return data.apply(repeat, batch_size=shape)
