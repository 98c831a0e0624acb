"""DUAL's actor-critic update as one TorchRL loss (Alg. 1 lines 7-8 and 15-16)."""

from __future__ import annotations

from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import dispatch
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import TensorSpec
from torchrl.objectives.common import LossModule

from torchrl_dual._utils import require_finite
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.objectives.weighted_map_actor import WeightedMAPActorLoss


class DUALLoss(LossModule):
    """DUAL's actor-critic update, Alg. 1 lines 7-8 (offline) and 15-16 (online).

    A critic loss chosen at construction and Eq. (7)'s weighted MAP actor read on its
    weights.

    ``forward`` returns every term, as TorchRL's ``IQLLoss`` does: the critic's
    (:class:`~torchrl_dual.objectives.IQLCriticLoss`: ``loss_qvalue``, ``loss_value``;
    :class:`~torchrl_dual.objectives.CalQLLoss`: ``loss_qvalue``, ``loss_cql`` and, in its
    Lagrange form, ``loss_alpha_prime``; :class:`~torchrl_dual.objectives.SO2QLoss`:
    ``loss_qvalue``), Eq. (7)'s ``loss_actor``, and the metrics ``weight_mean``,
    ``log_prob`` and ``actor_std``. Two ways to train it:

    1. TorchRL's: one optimizer over ``loss.parameters()`` stepped on the sum of the
       ``loss_*`` entries, then ``SoftUpdate(loss, tau=...).step()``. The actor then reads
       the critic before this step's update, as ``IQLLoss``'s joint step does.
    2. Alg. 1's: a critic step, the target update, then an actor step on the updated
       critic, with two optimizers over :meth:`critic_parameters` and
       :meth:`actor_parameters` (:class:`~torchrl_dual.trainers.CriticActorStepper` does
       it; the recipe runs this order). :meth:`critic_loss` and :meth:`actor_loss` are the
       two halves.

    **The critic** is any TorchRL loss that implements the critic protocol: a
    ``critic_terms(tensordict) -> dict`` of its ``loss_*`` terms, a ``critic_parameters()``
    list for its optimizer and a ``critic_out_keys`` tuple, plus what
    :meth:`WeightedMAPActorLoss.from_iql` reads (``qvalue_network`` and
    ``target_qvalue_network_params``; ``value_network`` and ``value_network_params`` for
    the ``"advantage"`` weighting). The three critics above implement it. Its parameters
    become this loss's own (``qvalue_network_params``, ``target_qvalue_network_params``,
    ...), so TorchRL's ``SoftUpdate``, ``state_dict`` and ``.to(device)`` see one module;
    the actor's are ``actor_params``. Eq. (7) always reads the critic this loss trains.

    Args:
        actor (LastLayerActor): ``π_θ``'s mean ``μ(s) = τ_a0`` and learnable ``σ̄`` (e.g.
            :class:`~torchrl_dual.modules.PlannerActor` on the distilled planner).
        critic (LossModule): the critic loss (see above).

    Keyword Args:
        weighting (str): Eq. (7)'s weights, one of
            :data:`~torchrl_dual.objectives.WEIGHTINGS`. Defaults to ``"advantage"``.
        temperature (float): ``β`` of the advantage weights. Defaults to ``3.0``.
        max_weight (float): their clip ``w_max``. Defaults to ``100.0``.
        entropy_coef (float): ``α`` of the ``"sac"`` weighting. Defaults to ``0.2``.
        action_spec (TensorSpec, optional): the env's action spec; required by ``"sac"``.
        reduction (str, optional): ``"none"`` | ``"mean"`` | ``"sum"``, set on both parts.
            Defaults to each part's own (``"mean"``).
        check_finite (bool): raise, naming the batch's first non-finite entry, when a
            critic term, the actor's input or Eq. 7's weights hold a NaN or inf (a host
            read each; skipped under ``torch.compile`` and CUDA-graph capture). Defaults
            to ``True``; ``False`` skips them all.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> from torchrl_dual.modules import LinearHeadActor
        >>> from torchrl_dual.objectives import IQLCriticLoss
        >>> critic = IQLCriticLoss(
        ...     ValueOperator(MLP(in_features=5, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation", "action"]),
        ...     ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]),
        ...                   in_keys=["observation"]),
        ...     loss_function="l2", expectile=0.7)
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
        >>> loss = DUALLoss(actor, critic, temperature=3.0)
        >>> loss.make_value_estimator(gamma=0.99)
        >>> updater = SoftUpdate(loss, tau=0.005)
        >>> optimizer = torch.optim.Adam(loss.parameters(), lr=3e-4)
        >>> batch = TensorDict({
        ...     "observation": torch.randn(8, 3), "action": torch.rand(8, 2) * 2 - 1,
        ...     "next": {"observation": torch.randn(8, 3), "reward": torch.randn(8, 1),
        ...              "done": torch.zeros(8, 1, dtype=torch.bool),
        ...              "terminated": torch.zeros(8, 1, dtype=torch.bool)}}, [8])
        >>> out = loss(batch)
        >>> sorted(key for key in out.keys() if key.startswith("loss_"))
        ['loss_actor', 'loss_qvalue', 'loss_value']
        >>> sum(out[key] for key in out.keys() if key.startswith("loss_")).backward()
        >>> optimizer.step()
        >>> updater.step()
    """

    critic: LossModule
    actor_objective: WeightedMAPActorLoss

    def __init__(
        self,
        actor: LastLayerActor,
        critic: LossModule,
        *,
        weighting: str = "advantage",
        temperature: float = 3.0,
        max_weight: float = 100.0,
        entropy_coef: float = 0.2,
        action_spec: TensorSpec | None = None,
        reduction: str | None = None,
        check_finite: bool = True,
    ) -> None:
        missing = [
            name
            for name in ("critic_terms", "critic_parameters", "critic_out_keys")
            if not hasattr(critic, name)
        ]
        if not isinstance(critic, LossModule) or missing:
            raise TypeError(
                f"DUALLoss's critic must be a TorchRL LossModule with the critic protocol "
                f"(critic_terms, critic_parameters, critic_out_keys); {type(critic).__name__} "
                f"lacks {missing or 'LossModule'}. Use IQLCriticLoss, CalQLLoss or SO2QLoss."
            )
        super().__init__()
        objective = WeightedMAPActorLoss.from_iql(
            actor,
            critic,
            weighting=weighting,
            temperature=temperature,
            max_weight=max_weight,
            entropy_coef=entropy_coef,
            action_spec=action_spec,
            check_finite=check_finite,
        )
        self.__dict__["critic"] = critic  # their state is adopted below: one module tree
        self.__dict__["actor_objective"] = objective
        # one record of which target parameters have an updater (TorchRL's SoftUpdate)
        self._has_update_associated = critic._has_update_associated
        self._adopt()
        if reduction is not None:
            self.reduction = reduction

    @property
    def check_finite(self) -> bool:
        """Whether the terms are checked finite (the actor loss's setting, shared by both parts)."""
        return self.actor_objective.check_finite

    @check_finite.setter
    def check_finite(self, value: bool) -> None:
        self.actor_objective.check_finite = value

    # ------------------------------------------------------------------ one module tree
    def _parts(self) -> tuple[LossModule, LossModule]:
        return self.critic, self.actor_objective

    def _adopt(self) -> None:
        """Registers the parts' submodules, parameters and buffers as this loss's own.

        They keep their names: TorchRL's target updaters look for
        ``target_*_params`` among a loss's direct children. The critic's copy of the
        actor (Cal-QL's and SO2's policy, which holds the actor's own parameters) is
        left out: the actor is the actor's.
        """
        actor_tensors = {id(p) for p in self.actor_objective.parameters()}
        for part in self._parts():
            for kind in ("_modules", "_parameters", "_buffers"):
                mine = getattr(self, kind)
                for name, value in getattr(part, kind).items():
                    if value is None:
                        continue
                    leaves = value.parameters() if isinstance(value, nn.Module) else [value]
                    leaves = list(leaves)
                    if (
                        part is self.critic
                        and leaves
                        and all(id(p) in actor_tensors for p in leaves)
                    ):
                        continue
                    if name in mine and mine[name] is not value:
                        raise RuntimeError(f"DUALLoss: both parts hold a {name!r}.")
                    self.__dict__.pop(name, None)  # e.g. LossModule's `_value_estimator = None`
                    mine[name] = value

    def _apply(self, fn: Any, *args: Any, **kwargs: Any) -> DUALLoss:
        """Casts and moves the parts, then takes their new state.

        Each part refreshes its own caches and replaces its own buffers.
        """
        for part in self._parts():
            part._apply(fn, *args, **kwargs)
        self._erase_cache()
        for kind in ("_modules", "_parameters", "_buffers"):
            getattr(self, kind).clear()
        self._adopt()
        return self

    @property
    def reduction(self) -> str:
        """Both parts' reduction, ``"mean"``, ``"sum"`` or ``"none"``; setting it sets both."""
        return self.actor_objective.reduction

    @reduction.setter
    def reduction(self, value: str) -> None:
        for part in self._parts():
            part.reduction = value

    def critic_parameters(self) -> list[torch.Tensor]:
        """What the critic's optimizer steps (the critic's ``critic_parameters()``)."""
        return list(self.critic.critic_parameters())

    def actor_parameters(self) -> list[torch.Tensor]:
        """What the actor's optimizer steps: ``μ``'s weights and ``σ̄`` (Eq. 7)."""
        return list(self.actor_objective.parameters())

    def reset_parameters_recursive(self) -> None:
        """Re-initialises what this loss owns: the critic's networks and the actor."""
        for part in self._parts():
            part.reset_parameters_recursive()

    # ------------------------------------------------------------------ TorchRL's hooks
    def make_value_estimator(self, value_type: Any = None, **hyperparams: Any) -> None:
        """The critic's ``make_value_estimator`` (e.g. ``gamma=0.99``)."""
        self.critic.make_value_estimator(value_type, **hyperparams)
        self._adopt()

    def _forward_value_estimator_keys(self, **kwargs: Any) -> None:
        pass

    @property
    def value_estimator(self) -> Any:
        """The critic's value estimator (TD targets of Alg. 1 lines 7 and 15)."""
        return self.critic.value_estimator

    @property
    def tensor_keys(self) -> Any:
        """The critic's keys, which Eq. 7's actor reads too.

        The actor reads the same observation, action and critic outputs;
        ``set_keys`` renames them in both parts.
        """
        return self.critic.tensor_keys

    def set_keys(self, **kwargs: NestedKey) -> None:
        """Renames keys in every part that reads them.

        A name no part knows raises ``ValueError`` listing the valid ones.
        """
        known = [set(vars(part.tensor_keys)) for part in self._parts()]
        unknown = set(kwargs) - set.union(*known)
        if unknown:
            raise ValueError(
                f"{sorted(unknown)} are not keys of DUALLoss; valid: {sorted(set.union(*known))}."
            )
        for part, names in zip(self._parts(), known, strict=True):
            own = {name: key for name, key in kwargs.items() if name in names}
            if own:
                part.set_keys(**own)

    def set_vmap_randomness(self, value: str) -> None:
        """TorchRL's ``set_vmap_randomness``, for both parts' ensemble evaluations."""
        super().set_vmap_randomness(value)
        for part in self._parts():
            part.set_vmap_randomness(value)

    def _make_vmap(self) -> None:
        """Nothing of its own to rebuild: the parts rebuild theirs."""

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys both parts read, each once, in order."""
        return list(dict.fromkeys(key for part in self._parts() for key in part.in_keys))

    @property
    def out_keys(self) -> list[str]:
        """The critic's ``loss_*`` terms, then the actor's term and metrics."""
        return [*self.critic.critic_out_keys, *self.actor_objective.out_keys]

    # ------------------------------------------------------------------ the terms
    def critic_loss(self, tensordict: TensorDictBase) -> tuple[dict[str, torch.Tensor], dict]:
        """The critic's terms (Alg. 1 lines 7 and 15); no metadata.

        Checked finite when ``check_finite``.
        """
        terms = self.critic.critic_terms(tensordict)
        if self.check_finite:
            for name, term in terms.items():
                require_finite(term, f"DUALLoss's {name}", tensordict)
        return terms, {}

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Eq. (7)'s weighted MAP actor loss on the critic's current weights.

        Returns ``loss_actor`` (reduced) and the metrics ``weight_mean``,
        ``log_prob``, ``actor_std``; writes the per-sample weights under
        ``actor_weight``.
        """
        out = self.actor_objective(tensordict)
        return out["loss_actor"], {key: out[key] for key in out.keys() if key != "loss_actor"}

    @dispatch
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Every term (the critic's, then Eq. 7's ``loss_actor``) and the actor's metrics."""
        critic, _ = self.critic_loss(tensordict)
        return TensorDict(critic).update(self.actor_objective(tensordict))
