"""TorchRL's IQL loss with the target Q and ``V(s)`` computed once per batch.

TorchRL 0.14's :class:`~torchrl.objectives.IQLLoss` computes its three terms in three
independent methods. Two of them need the same quantities: ``value_loss`` evaluates the
target twin Q networks at ``(s, a)`` and ``V(s)`` (with gradient), and ``actor_loss``
evaluates both again (``V(s)`` without gradient) for the advantage weight
``exp(β (min Q̄(s, a) − V(s)))``. :class:`OnePassIQLLoss` evaluates each once: the
advantage uses ``V(s)`` detached, so the actor's gradient still never reaches V, and
every number is the same operation on the same inputs as TorchRL's, hence bitwise the
same losses and gradients (``tests/objectives/test_one_pass_iql.py``). On a CPU at
256 x 2 networks and batches of 256 this is 6 of IQL's 21 ``linear`` calls and their
functional-call overhead: about 15 % of the update (docs/benchmarks.md).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import dispatch
from torchrl.objectives import IQLLoss

from torchrl_dual.objectives.ensemble_q import EnsembleMLPCalls

_PARAMS = tuple(
    f"{prefix}{name}_network_params"
    for prefix in ("", "target_")
    for name in ("actor", "qvalue", "value")
)
"""The functional parameter groups whose weak references TorchRL clears under compile."""


class OnePassIQLLoss(EnsembleMLPCalls, IQLLoss):
    """TorchRL's IQL loss with the target Q and ``V(s)`` shared between its terms.

    :class:`~torchrl.objectives.IQLLoss` whose :meth:`forward` (and :meth:`terms`) share
    the target Q and ``V(s)`` between the value and the actor losses.

    Same constructor, parameters, keys and outputs as TorchRL's class; ``actor_loss``,
    ``value_loss`` and ``qvalue_loss`` remain TorchRL's for callers that need one term.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import NormalParamExtractor, TensorDictModule
        >>> from torch import nn
        >>> from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
        >>> obs, act = 3, 2
        >>> actor = ProbabilisticActor(
        ...     TensorDictModule(nn.Sequential(MLP(in_features=obs, out_features=2 * act,
        ...                                        num_cells=[16]), NormalParamExtractor()),
        ...                      in_keys=["observation"], out_keys=["loc", "scale"]),
        ...     in_keys=["loc", "scale"], distribution_class=TanhNormal)
        >>> qvalue = ValueOperator(MLP(in_features=obs + act, out_features=1, num_cells=[16]),
        ...                        in_keys=["observation", "action"])
        >>> value = ValueOperator(MLP(in_features=obs, out_features=1, num_cells=[16]),
        ...                       in_keys=["observation"])
        >>> loss = OnePassIQLLoss(actor, qvalue, value, loss_function="l2")
        >>> batch = TensorDict({
        ...     "observation": torch.randn(8, obs), "action": torch.rand(8, act) * 1.8 - 0.9,
        ...     "next": {"observation": torch.randn(8, obs), "reward": torch.randn(8, 1),
        ...              "done": torch.zeros(8, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(8, 1, dtype=torch.bool)}}, [8])
        >>> sorted(loss.terms(batch))
        ['loss_actor', 'loss_qvalue', 'loss_value']
        >>> bool(loss.terms(batch)["loss_value"] == loss.value_loss(batch)[0])
        True
    """

    def terms(self, tensordict: TensorDictBase) -> dict[str, torch.Tensor]:
        """The three losses of IQL on one batch, each equal to its TorchRL method's.

        ``loss_qvalue`` (TD to ``r + γ V(s')``), ``loss_value`` (the expectile of
        ``min Q̄(s, a) − V(s)``) and ``loss_actor`` (``−exp(β (min Q̄ − V)) log
        π(a|s)``, the weight clipped at 100). Writes ``log_prob`` (detached) into
        ``tensordict`` as ``actor_loss`` does.
        """
        return self._terms(tensordict)[0]

    def _terms(self, tensordict: TensorDictBase) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """:meth:`terms` and the TD errors of the Q networks (``[num_qvalue_nets, *B]``)."""
        keys = self.tensor_keys
        with self.actor_network_params.to_module(self.actor_network, preserve_module_state=False):
            dist = self.actor_network.get_dist(tensordict)
        log_prob = dist.log_prob(tensordict[keys.action])

        td_q = tensordict.select(*self.qvalue_network.in_keys, strict=False)
        td_q = self._vmap_qvalue_networkN0(td_q, self.target_qvalue_network_params)
        min_q = td_q.get(keys.state_action_value).min(0)[0].squeeze(-1)
        if log_prob.shape != min_q.shape:
            raise RuntimeError(f"Losses shape mismatch: {log_prob.shape} and {min_q.shape}")

        td_v = tensordict.select(*self.value_network.in_keys, strict=False)
        with self.value_network_params.to_module(self.value_network, preserve_module_state=False):
            self.value_network(td_v)
        value = td_v.get(keys.value).squeeze(-1)

        weight = torch.exp((min_q - value.detach()) * self.temperature).clamp_max(100)
        tensordict.set(keys.log_prob, log_prob.detach())
        loss_actor = self._reduce_loss(-(weight * log_prob), tensordict=tensordict)
        loss_value = self._reduce_loss(
            self.loss_value_diff(min_q - value, self.expectile), tensordict=tensordict
        )
        loss_qvalue, metadata = self.qvalue_loss(tensordict)
        self._clear_weakrefs(tensordict, *_PARAMS)
        out = {"loss_actor": loss_actor, "loss_qvalue": loss_qvalue, "loss_value": loss_value}
        return out, metadata["td_error"]

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """TorchRL's ``IQLLoss.forward`` on :meth:`terms`.

        The three losses, the entropy estimate ``−mean log π(a|s)`` and the batch's
        priority (the max TD error over the Q networks) written into ``tensordict``.
        """
        out, td_error = self._terms(tensordict)
        shapes = {name: term.shape for name, term in out.items()}
        if len(set(shapes.values())) > 1:
            raise RuntimeError(f"Losses shape mismatch: {shapes}")
        tensordict.set(self.tensor_keys.priority, td_error.detach().max(0).values)
        entropy = -tensordict.get(self.tensor_keys.log_prob).detach()
        if self.reduction == "none":
            td_out = TensorDict(out, batch_size=tensordict.batch_size)
            if self.scalar_output_mode == "non_tensor":
                td_out.set_non_tensor("entropy", entropy.mean())
        else:
            td_out = TensorDict({**out, "entropy": entropy.mean()})
        self._clear_weakrefs(tensordict, td_out, *_PARAMS)
        return td_out
