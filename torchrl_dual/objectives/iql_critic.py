"""IQL's critics without its actor: the critic of DUAL (Alg. 1 lines 7 and 15)."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule, dispatch
from torch import nn
from torchrl.modules import ProbabilisticActor
from torchrl.objectives import IQLLoss

from torchrl_dual.objectives.ensemble_q import EnsembleMLPCalls


class _NoActor(nn.Module):
    """The actor slot of TorchRL's ``IQLLoss``, which cannot be left empty: refuses to act.

    A module without parameters, so no actor weights are held or saved.
    """

    def forward(self, *observations: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        raise RuntimeError(
            "IQLCriticLoss has no actor: train one with WeightedMAPActorLoss or DUALLoss (Eq. 7)."
        )


class IQLCriticLoss(EnsembleMLPCalls, IQLLoss):
    """IQL's critics (Kostrikov et al. 2022, Eq. 5-6): TorchRL's ``IQLLoss`` without the actor.

    :class:`~torchrl.objectives.IQLLoss`'s expectile value loss and twin-Q TD loss.

    * ``loss_value``: ``E[L_τ(min_k Q̄_k(s, a) − V(s))]``, with ``L_τ(u) = |τ − 1(u < 0)| u²``
      the expectile regression at ``expectile = τ`` and ``Q̄`` the target Q networks;
    * ``loss_qvalue``: ``Σ_k E[(Q_k(s, a) − r − γ (1 − d) V(s'))²]`` (``loss_function``).

    This is DUAL's critic (Alg. 1 lines 7 and 15): :class:`~torchrl_dual.objectives.DUALLoss`
    pairs it with Eq. (7)'s actor. Construction, parameters (``qvalue_network_params``,
    ``target_qvalue_network_params``, ``value_network_params``), keys, value estimator and
    ``SoftUpdate`` are TorchRL's; the actor slot holds a parameterless stand-in that raises
    if asked to act, so ``actor_loss`` is unavailable.

    Args:
        qvalue_network (TensorDictModule): ``Q(s, a)``, copied into ``num_qvalue_nets``
            networks (TorchRL redraws the weights of all but the first).
        value_network (TensorDictModule): ``V(s)``; its ``in_keys`` are the observation keys.

    Keyword Args:
        num_qvalue_nets (int): size of the Q ensemble. Defaults to ``2``.
        loss_function (str): the TD distance, ``"l2"``, ``"l1"`` or ``"smooth_l1"``.
            Defaults to ``"smooth_l1"`` (TorchRL's; IQL's paper uses ``"l2"``).
        expectile (float): ``τ``. Defaults to ``0.5`` (TorchRL's; IQL's paper uses 0.7 for
            locomotion and 0.9 for AntMaze).
        gamma (float, optional): the discount; prefer ``make_value_estimator(gamma=...)``.
        priority_key (NestedKey, optional): where ``forward`` writes the TD-error priority.
        reduction (str, optional): ``"none"`` | ``"mean"`` | ``"sum"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> qvalue = ValueOperator(MLP(in_features=5, out_features=1, num_cells=[16]),
        ...     in_keys=["observation", "action"])
        >>> value = ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]),
        ...     in_keys=["observation"])
        >>> loss = IQLCriticLoss(qvalue, value, loss_function="l2", expectile=0.7)
        >>> loss.make_value_estimator(gamma=0.99)
        >>> updater = SoftUpdate(loss, tau=0.005)
        >>> batch = TensorDict({
        ...     "observation": torch.randn(8, 3), "action": torch.randn(8, 2),
        ...     "next": {"observation": torch.randn(8, 3), "reward": torch.randn(8, 1),
        ...              "done": torch.zeros(8, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(8, 1, dtype=torch.bool)}}, [8])
        >>> out = loss(batch)
        >>> sorted(out.keys())
        ['loss_qvalue', 'loss_value']
        >>> (out["loss_qvalue"] + out["loss_value"]).backward()
    """

    out_keys = ["loss_qvalue", "loss_value"]
    critic_out_keys = ("loss_qvalue", "loss_value")
    """The terms :meth:`critic_terms` returns (the critic protocol of ``DUALLoss``)."""

    def __init__(
        self,
        qvalue_network: TensorDictModule,
        value_network: TensorDictModule,
        *,
        num_qvalue_nets: int = 2,
        loss_function: str = "smooth_l1",
        expectile: float = 0.5,
        gamma: float | None = None,
        priority_key: str | None = None,
        reduction: str | None = None,
    ) -> None:
        stand_in = ProbabilisticActor(
            TensorDictModule(_NoActor(), in_keys=value_network.in_keys, out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"],
            distribution_class=torch.distributions.Normal,
        )
        super().__init__(
            stand_in,
            qvalue_network,
            value_network,
            num_qvalue_nets=num_qvalue_nets,
            loss_function=loss_function,
            expectile=expectile,
            gamma=gamma,
            priority_key=priority_key,
            reduction=reduction,
        )

    def critic_terms(self, tensordict: TensorDictBase) -> dict[str, torch.Tensor]:
        """The two losses of one critic step, ``loss_qvalue`` and ``loss_value``.

        Each is TorchRL's ``IQLLoss`` method's (the class docstring).
        """
        return {
            "loss_qvalue": self.qvalue_loss(tensordict)[0],
            "loss_value": self.value_loss(tensordict)[0],
        }

    def critic_parameters(self) -> list[nn.Parameter]:
        """What the critic's optimizer steps: the Q networks, then ``V``."""
        return [
            *self.qvalue_network_params.values(True, True),
            *self.value_network_params.values(True, True),
        ]

    def reset_parameters_recursive(self) -> None:
        """Re-initialises the Q networks (their targets too) and ``V``; there is no actor."""
        for name in ("qvalue_network", "value_network"):
            self._reset_module_parameters(name, getattr(self, name))

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Refuses: this loss has no actor (DUAL's is :class:`WeightedMAPActorLoss`, Eq. 7).

        Args:
            tensordict (TensorDictBase): unused.

        Raises:
            RuntimeError: always; :class:`DUALLoss` pairs this critic with the actor's loss.
        """
        raise RuntimeError(
            "IQLCriticLoss has no actor loss: DUAL's is WeightedMAPActorLoss (Eq. 7), and "
            "DUALLoss pairs the two."
        )

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """``loss_qvalue`` and ``loss_value``; writes the TD-error priority.

        A ``[*B]`` TensorDict under ``reduction="none"``; the priority is the max
        over the Q networks.
        """
        loss_qvalue, metadata = self.qvalue_loss(tensordict)
        loss_value = self.value_loss(tensordict)[0]
        tensordict.set(self.tensor_keys.priority, metadata["td_error"].max(0).values)
        batch_size = tensordict.batch_size if self.reduction == "none" else []
        return TensorDict(
            {"loss_qvalue": loss_qvalue, "loss_value": loss_value}, batch_size=batch_size
        )
