"""Diff-QL's actor loss, of the recipe's ``diffql`` and ``diffql_la`` baselines.

Wang et al. 2023, "Diffusion policies as an expressive policy class for offline RL".

``L(θ) = L_bc(θ) − η · mean Q(s, a_π) / mean |Q(s, a_π)|``: ``L_bc`` is TorchRL's
:class:`~torchrl.objectives.DiffusionBCLoss` (ε-prediction on the batch actions), ``a_π``
a sample of the actor's stochastic DDPM chain with gradients through all ``N`` denoising
steps, clamped to the action box (Wang et al. clip it too), and the normaliser
``mean |Q|`` is detached (Wang et al.'s). ``Q`` is any ``(observation, action) -> [*B]``
whose weights do not train here; :func:`min_q` is ``min_k Q_k`` of twin critics with
detached weights (:meth:`DiffQLActorLoss.from_iql` reads TorchRL ``IQLLoss``'s).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import DiffusionActor
from torchrl.objectives import DiffusionBCLoss, LossModule


def min_q(
    qvalue_network: TensorDictModule,
    qvalue_params: TensorDictBase,
    observation: torch.Tensor,
    action: torch.Tensor,
    *,
    key: NestedKey = "state_action_value",
    observation_key: NestedKey = "observation",
    action_key: NestedKey = "action",
) -> torch.Tensor:
    """``min_k Q_k(s, a)`` of the critics ``qvalue_params``, ``[*B]``, with detached weights.

    ``qvalue_params`` has a leading dimension ``k`` (e.g.
    ``IQLLoss.qvalue_network_params``). Gradients reach ``action`` (and through it the
    actor), never the critic. The network reads ``s`` and ``a`` under
    ``observation_key`` and ``action_key`` and writes ``Q`` under ``key``.

    Examples:
        >>> from torch import nn
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import TensorDictModule
        >>> _ = torch.manual_seed(0)
        >>> net = TensorDictModule(nn.Bilinear(2, 2, 1), in_keys=["observation", "action"],
        ...                        out_keys=["state_action_value"])
        >>> one = TensorDict.from_module(net).detach()
        >>> twins = torch.stack([one, one * 2])  # Q_2 = 2 Q_1
        >>> s, a = torch.randn(4, 2), torch.randn(4, 2, requires_grad=True)
        >>> q = min_q(net, twins, s, a)
        >>> q1 = net(TensorDict(observation=s, action=a, batch_size=[4]))["state_action_value"]
        >>> torch.equal(q, torch.minimum(q1, 2 * q1).squeeze(-1)), q.requires_grad
        (True, True)
    """
    td = TensorDict(batch_size=observation.shape[:-1])
    td.set(observation_key, observation)
    td.set(action_key, action)
    values = []
    for member in qvalue_params.detach().unbind(0):
        with member.to_module(qvalue_network, preserve_module_state=False):  # traceable
            values.append(qvalue_network(td.clone(False)).get(key))
    return torch.stack(values).min(0).values.squeeze(-1)


class DiffQLActorLoss(LossModule):
    """Diff-QL's actor loss ``L_bc + η · (−mean Q(s, a_π) / mean |Q(s, a_π)|)``.

    ``L_bc`` is TorchRL's :class:`~torchrl.objectives.DiffusionBCLoss` on the batch
    actions; ``a_π`` the actor's stochastic DDPM chain (``ExplorationType.RANDOM``),
    differentiable through all ``N`` steps and clamped by ``box``; ``Q`` is ``q_value``
    (:func:`min_q` with critic weights detached, from :meth:`from_iql`) and the
    normaliser ``mean |Q|`` is detached, so the Q-term is invariant to the critic's scale
    and trains the actor only. A TorchRL ``LossModule``: its keys are set with
    :meth:`set_keys` (``observation``, ``action``), its output is a ``TensorDict`` whose
    one differentiable term is ``loss_actor``; its two parts are the detached metrics
    ``bc_term`` (``L_bc``) and ``q_term`` (the normalised Q-term before ``η``).

    Args:
        actor (DiffusionActor): TorchRL's DDPM actor.
        q_value (callable): ``(observation, action) -> Q [*B]``, differentiable in the
            action; its own weights must not receive gradients.
        box (callable): ``action -> action`` clamped to the env's action box.

    Keyword Args:
        eta (float): ``η``, the weight of the normalised Q-term.
        reduction (str): ``"mean"`` (default), ``"sum"`` or ``"none"``: per sample,
            ``L_bc`` averaged over the action dimensions plus ``η · (−Q(s, a_π) / mean |Q|)``,
            shaped like the batch (the normaliser stays the batch mean).

    Examples:
        >>> from torch import nn
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import DiffusionActor
        >>> _ = torch.manual_seed(0)
        >>> score = nn.Sequential(nn.Linear(2 + 3 + 1, 16), nn.SiLU(), nn.Linear(16, 2))
        >>> actor = DiffusionActor(2, score_network=score, num_steps=3)
        >>> q_value = lambda s, a: -(a - 0.5).square().sum(-1)  # best action: 0.5
        >>> loss = DiffQLActorLoss(actor, q_value, lambda a: a.clamp(-1, 1), eta=1.0)
        >>> batch = TensorDict(observation=torch.randn(8, 3), action=torch.rand(8, 2),
        ...                    batch_size=[8])
        >>> out = loss(batch)
        >>> sorted(out.keys())
        ['bc_term', 'loss_actor', 'q_pi', 'q_term']
        >>> out["loss_actor"].backward()
        >>> all(p.grad is not None for p in actor.parameters())
        True
        >>> loss.reduction = "none"
        >>> loss(batch)["loss_actor"].shape
        torch.Size([8])
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observation (NestedKey): the state ``s``. Defaults to ``"observation"``.
            action (NestedKey): the data action of ``L_bc``. Defaults to ``"action"``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"

    default_keys = _AcceptedKeys
    out_keys = ["loss_actor", "bc_term", "q_term", "q_pi"]

    def __init__(
        self,
        actor: DiffusionActor,
        q_value: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
        box: Callable[[torch.Tensor], torch.Tensor],
        *,
        eta: float,
        reduction: str = "mean",
    ) -> None:
        if reduction not in ("mean", "sum", "none"):
            raise ValueError(f"reduction must be 'mean', 'sum' or 'none', got {reduction!r}")
        super().__init__()
        self.actor, self.q_value, self.box, self.eta = actor, q_value, box, eta
        self.bc_loss = DiffusionBCLoss(actor, reduction="none")  # reduced in forward
        self.reduction = reduction

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads: the observation and the data action."""
        return [self.tensor_keys.observation, self.tensor_keys.action]

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        """``set_keys`` reaches ``L_bc``'s loss too."""
        keys = {k: v for k, v in kwargs.items() if k in ("observation", "action")}
        if keys:
            self.bc_loss.set_keys(**keys)

    def reset_parameters_recursive(self) -> None:
        """Re-initialises the actor; the critic behind ``q_value`` is only read."""
        self.bc_loss.reset_parameters_recursive()

    @classmethod
    def from_iql(
        cls,
        actor: DiffusionActor,
        iql_loss,
        box: Callable[[torch.Tensor], torch.Tensor],
        *,
        eta: float,
        reduction: str = "mean",
    ) -> DiffQLActorLoss:
        """Builds the loss on the twin Q networks of a TorchRL ``IQLLoss``.

        It reads their current, not their target, weights (:func:`min_q`); they read
        the state under this loss's ``tensor_keys.observation`` and the action under
        ``iql_loss.tensor_keys.action``.
        """

        def q_value(observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
            return min_q(
                iql_loss.qvalue_network,
                iql_loss.qvalue_network_params,
                observation,
                action,
                key=iql_loss.tensor_keys.state_action_value,
                observation_key=loss.tensor_keys.observation,  # as renamed by set_keys
                action_key=iql_loss.tensor_keys.action,
            )

        loss = cls(actor, q_value, box, eta=eta, reduction=reduction)
        return loss

    def sample_actions(self, observation: torch.Tensor) -> torch.Tensor:
        """``a_π``, differentiable with respect to the actor's weights."""
        with set_exploration_type(ExplorationType.RANDOM):
            return self.box(self.actor.module(observation))

    def q_term(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``(−mean Q(s, a_π) / mean |Q(s, a_π)|, mean Q(s, a_π))``."""
        q = self.q_value(observation, self.sample_actions(observation))
        return -q.mean() / _scale(q), q.mean().detach()

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """Diff-QL's actor loss ``L_bc + η · q_term`` and its two parts.

        Args:
            tensordict (TensorDictBase): the batch ``[*B]`` with the observation and the data
                action.

        Returns:
            ``loss_actor`` (a scalar, or ``[*B]`` under ``reduction="none"``) and the detached
            ``bc_term``, ``q_term`` and ``q_pi`` (the mean ``Q(s, a_π)``).
        """
        observation = tensordict.get(self.tensor_keys.observation)
        bc = self.bc_loss(tensordict)["loss_diffusion_bc"]  # [*B, action dim]
        if self.reduction == "mean":
            bc = bc.mean()
            q_term, q_pi = self.q_term(observation)
        else:  # per sample: L_bc over the action dims, the Q-term over the batch's scale
            q = self.q_value(observation, self.sample_actions(observation))
            bc, q_term = (
                _reduce(bc.mean(-1), self.reduction),
                _reduce(-q / _scale(q), self.reduction),
            )
            q_pi = q.detach()
        return TensorDict(
            loss_actor=bc + self.eta * q_term,
            bc_term=bc.detach(),
            q_term=q_term.detach(),
            q_pi=q_pi,
        )


def _scale(q: torch.Tensor) -> torch.Tensor:
    """The Q-term's normaliser ``mean |Q|``, detached (Wang et al.'s)."""
    return q.abs().mean().detach().clamp_min(1e-6)


def _reduce(loss: torch.Tensor, reduction: str) -> torch.Tensor:
    """``sum`` or ``none`` (the mean is taken in :meth:`DiffQLActorLoss.forward` itself)."""
    return loss.sum() if reduction == "sum" else loss
