"""The weighted MAP actor loss of DUAL (Eq. 7)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch.distributions import Normal
from torchrl.data import TensorSpec
from torchrl.objectives.common import LossModule
from torchrl.objectives.utils import _vmap_func  # TorchRL's own ensemble evaluation

from torchrl_dual._utils import check_finite, read_loss_input, require_finite
from torchrl_dual.modules.actors.action_box import ActionBox
from torchrl_dual.modules.actors.last_layer_actor import LastLayerActor
from torchrl_dual.objectives.ensemble_q import EnsembleMLP

WEIGHTINGS = ("advantage", "sac", "uniform")


class WeightedMAPActorLoss(LossModule):
    """Weighted maximum-a-posteriori actor loss, Eq. (7) of DUAL.

    The actor is the Gaussian ``π_θ(a | s) = N(μ_θ(s), σ̄²)`` whose mean ``μ_θ(s) = τ_{a_0}``
    comes from the distilled one-step planner (:class:`~torchrl_dual.modules.PlannerActor`)
    or any :class:`~torchrl_dual.modules.LastLayerActor`, and ``σ̄`` is a learnable, clamped,
    per-dimension standard deviation. Eq. (7) reads

    ``L_π(θ) = −E_{(s,a)∼D}[Q_φ(s, a) · log π_θ(a | s)] − log p(θ)``.

    Raw Q-values can be negative (sparse or negative rewards), which turns the weighted
    likelihood into a repulsion from data actions and makes ``exp(−L_π)`` unnormalisable,
    which breaks the posterior reading of Eq. (8). The loss therefore uses positive weights:

    * ``"advantage"`` (default): IQL's ``w = min(exp(β·(Q(s,a) − V(s))), w_max)``, with Q the
      minimum over the critic ensemble. The loss stays a weighted log-likelihood, so
      Thm. 3.3 and the closed-form Laplace of Eq. (8) apply as stated;
    * ``"sac"``: the Cal-QL / SAC actor loss ``−E_{s∼D, a∼π}[Q(s, a) − α·log π(a | s)]``
      with a reparameterised ``a``, the paper's Cal-QL variant (note after Thm. 3.3).
      ``a`` is the action the env executes, a draw of ``N(μ, σ̄²)`` clamped to the
      ``action_spec`` box, and ``log π`` its censored-Gaussian score
      (:class:`~torchrl_dual.modules.actors.action_box.ClippedNormal`): the critic never saw
      actions outside the box, and a Gaussian that climbs its extrapolation there leaves
      the box for good (:mod:`torchrl_dual.modules.actors.action_box`);
    * ``"uniform"``: ``w = 1``, plain behaviour cloning of the planner's first action.

    The prior ``p(θ)`` is flat, as in the paper (density 1); the Laplace step picks its
    own prior precision by the evidence. Gradients reach only the actor: critic
    parameters are read detached.

    Args:
        actor (LastLayerActor): the actor whose ``μ`` and ``σ̄`` are trained.

    Keyword Args:
        qvalue_network (TensorDictModule, optional): writes ``tensor_keys.state_action_value``
            from observation and action. Required unless ``weighting="uniform"``.
        value_network (TensorDictModule, optional): writes ``tensor_keys.value``;
            required for ``"advantage"``.
        qvalue_params (TensorDictBase, optional): parameters for ``qvalue_network`` with a
            leading ensemble dimension (e.g. ``IQLLoss.target_qvalue_network_params``);
            the minimum over the ensemble is used. Defaults to the module's own weights.
        value_params (TensorDictBase, optional): parameters for ``value_network``.
        weighting (str): one of :data:`WEIGHTINGS`. Defaults to ``"advantage"``.
        temperature (float): ``β`` of the advantage weights. Defaults to ``3.0``.
        max_weight (float): ``w_max``. Defaults to ``100.0``.
        entropy_coef (float): ``α`` of the ``"sac"`` variant. Defaults to ``0.2``.
        action_spec (TensorSpec, optional): the env's ``Bounded`` action spec (an
            ``Unbounded`` one for a space without bounds); required by ``"sac"``, whose
            Q is read at the sample clamped to it.
        reduction (str): ``"none"`` | ``"mean"`` | ``"sum"``. Defaults to ``"mean"``.
        check_finite (bool): raise on a NaN or inf in the observation, the action or the
            advantage weights, naming the batch's first bad entry (a host read each;
            skipped under ``torch.compile`` and CUDA-graph capture). Defaults to ``True``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.modules import MLP
        >>> from torchrl_dual.modules import LinearHeadActor
        >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2)
        >>> loss_fn = WeightedMAPActorLoss(actor, weighting="uniform")
        >>> td = TensorDict({"observation": torch.randn(8, 3), "action": torch.randn(8, 2)}, [8])
        >>> loss_fn(td)["loss_actor"].backward()
        >>> # the Cal-QL variant on a critic Q(s, a), its actions clamped to the box
        >>> from torchrl.data import Bounded
        >>> from torchrl.modules import ValueOperator
        >>> qvalue = ValueOperator(MLP(in_features=5, out_features=1, num_cells=[16]),
        ...     in_keys=["observation", "action"])
        >>> sac = WeightedMAPActorLoss(actor, qvalue_network=qvalue, weighting="sac",
        ...     action_spec=Bounded(-1.0, 1.0, shape=(2,)))
        >>> sac(td)["loss_actor"].backward()
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observation (NestedKey): the state. Defaults to ``"observation"``.
            action (NestedKey): the data action. Defaults to ``"action"``.
            state_action_value (NestedKey): the critic's Q output.
                Defaults to ``"state_action_value"``.
            value (NestedKey): the value network's output. Defaults to ``"state_value"``.
            weight (NestedKey): where the per-sample weights are written (for the
                Laplace fit to reuse them). Defaults to ``"actor_weight"``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        state_action_value: NestedKey = "state_action_value"
        value: NestedKey = "state_value"
        weight: NestedKey = "actor_weight"

    default_keys = _AcceptedKeys
    out_keys = ["loss_actor", "weight_mean", "log_prob", "actor_std"]

    actor: LastLayerActor
    actor_params: TensorDictParams
    target_actor_params: TensorDictParams

    def __init__(
        self,
        actor: LastLayerActor,
        *,
        qvalue_network: TensorDictModule | None = None,
        value_network: TensorDictModule | None = None,
        qvalue_params: TensorDictBase | None = None,
        value_params: TensorDictBase | None = None,
        weighting: str = "advantage",
        temperature: float = 3.0,
        max_weight: float = 100.0,
        entropy_coef: float = 0.2,
        action_spec: TensorSpec | None = None,
        reduction: str = "mean",
        check_finite: bool = True,
    ) -> None:
        super().__init__()
        if not isinstance(actor, LastLayerActor):
            raise TypeError(
                f"WeightedMAPActorLoss trains a LastLayerActor (mean mu(s) and learnable "
                f"sigma of Eq. 7: PlannerActor, LinearHeadActor or DDPMLastStepActor), got "
                f"{type(actor).__name__}; wrap a TorchRL actor with LinearHeadActor.from_actor."
            )
        if weighting not in WEIGHTINGS:
            raise ValueError(f"Unknown weighting {weighting!r}; choose one of {WEIGHTINGS}.")
        if weighting != "uniform" and qvalue_network is None:
            raise ValueError(f"weighting={weighting!r} needs a qvalue_network.")
        if weighting == "advantage" and value_network is None:
            raise ValueError("weighting='advantage' needs a value_network (V(s) of IQL).")
        if weighting == "sac" and action_spec is None:
            raise ValueError(
                "weighting='sac' reads Q at samples of the unbounded Gaussian N(mu, sigma^2): "
                "pass action_spec=env.action_spec so they are clamped to the executed action "
                "(torchrl.data.Unbounded(...) for an action space without bounds)."
            )
        # "sac": Q at the executed action (a submodule: its bounds follow .to(device))
        self.action_box = None if action_spec is None else ActionBox(action_spec)
        self.convert_to_functional(actor, "actor")
        # Critic modules and weights belong to the critic's loss: kept unregistered so the
        # actor's optimizer and state_dict never see them.
        self.__dict__["qvalue_network"] = qvalue_network
        self.__dict__["value_network"] = value_network
        self.__dict__["qvalue_params"] = qvalue_params
        self.__dict__["value_params"] = value_params
        self.weighting = weighting
        self.temperature = temperature
        self.max_weight = max_weight
        self.entropy_coef = entropy_coef
        self.reduction = reduction
        self.check_finite = check_finite

    @classmethod
    def from_iql(cls, actor: LastLayerActor, iql_loss, **kwargs) -> WeightedMAPActorLoss:
        """Builds the loss on the critics of a TorchRL ``IQLLoss`` (the target twin Q and V).

        Any critic loss with ``qvalue_network`` and target Q parameters works too,
        e.g. :class:`~torchrl_dual.objectives.CalQLLoss` (no V: ``weighting="sac"``
        or ``"uniform"`` only).
        """
        value_network = getattr(iql_loss, "value_network", None)
        with warnings.catch_warnings():  # TorchRL's warning is for a forward pass without
            # a target updater; here the critic's targets are only referenced
            warnings.filterwarnings("ignore", message="No target network updater")
            target_params = iql_loss.target_qvalue_network_params
        loss = cls(
            actor,
            qvalue_network=iql_loss.qvalue_network,
            value_network=value_network,
            qvalue_params=target_params,
            value_params=getattr(iql_loss, "value_network_params", None),
            **kwargs,
        )
        keys = {"state_action_value": iql_loss.tensor_keys.state_action_value}
        if value_network is not None:
            keys["value"] = iql_loss.tensor_keys.value
        loss.set_keys(**keys)
        return loss

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def _make_vmap(self) -> None:
        """TorchRL's hook of ``set_vmap_randomness``: the ensemble calls are rebuilt at next use."""
        self.__dict__["_ensemble_calls"] = {}

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads: the observation and the data action."""
        return [self.tensor_keys.observation, self.tensor_keys.action]

    # ------------------------------------------------------------------ critics
    def _evaluate(self, network, params, tensordict: TensorDictBase, key: NestedKey):
        td = tensordict.select(*network.in_keys, strict=False)
        if params is None:
            params = TensorDict.from_module(network)
        params = params.detach()
        if params.batch_dims == 0:
            with params.to_module(network, preserve_module_state=False):
                return network(td).get(key)
        # an ensemble (IQL's twin Q, SO2's 10): every member in one call, as TorchRL's
        # losses evaluate theirs (vmapped, with its vmap_randomness), as EnsembleMLP for a
        # plain MLP (the same numbers with less overhead)
        calls = self.__dict__.setdefault("_ensemble_calls", {})
        if id(network) not in calls:
            vmapped = _vmap_func(network, (None, 0), randomness=self.vmap_randomness)
            calls[id(network)] = EnsembleMLP.of(network, vmapped)
        return calls[id(network)](td, params).get(key).min(0).values

    def q_value(self, tensordict: TensorDictBase) -> torch.Tensor:
        """``min_k Q_k(s, a)`` with detached critic weights, shape ``[*B]``."""
        return self._evaluate(
            self.qvalue_network,
            self.qvalue_params,
            tensordict,
            self.tensor_keys.state_action_value,
        ).squeeze(-1)

    @torch.no_grad()
    def advantage_weights(self, tensordict: TensorDictBase) -> torch.Tensor:
        """IQL's advantage weights ``w = min(exp(β·(Q(s,a) − V(s))), w_max)`` of Eq. 7.

        The weights of the ``"advantage"`` weighting: ``Q`` is the minimum over the
        critic ensemble (``qvalue_params``), ``V`` the value network's, both read
        without gradient to the critic; ``β`` is ``temperature`` and ``w_max``
        ``max_weight``. :meth:`~torchrl_dual.modules.LaplaceEnsembleActor.fit_laplace`
        reuses them (``weight_fn=loss.advantage_weights``) so that Eq. 8's posterior is
        that of the loss the actor was trained with.

        Args:
            tensordict (TensorDictBase): transitions ``[*B]`` holding what the Q and
                value networks read (observation and action).

        Returns:
            Tensor: the weights, ``[*B]``, in ``(0, w_max]``.

        Raises:
            ValueError: a weight is NaN or inf (with ``check_finite``), naming the
                batch's first bad entry.

        Examples:
            >>> import torch
            >>> from torch import nn
            >>> from tensordict import TensorDict
            >>> from torchrl.modules import MLP, ValueOperator
            >>> from torchrl_dual.modules import LinearHeadActor
            >>> def constant(value, in_features):  # a network that outputs ``value``
            ...     net = MLP(in_features=in_features, out_features=1, depth=0)
            ...     _ = nn.init.zeros_(net[0].weight), nn.init.constant_(net[0].bias, value)
            ...     return net
            >>> loss = WeightedMAPActorLoss(
            ...     LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[16]), 2),
            ...     qvalue_network=ValueOperator(constant(1.0, 5),
            ...                                  in_keys=["observation", "action"]),
            ...     value_network=ValueOperator(constant(0.5, 3), in_keys=["observation"]),
            ...     temperature=2.0)
            >>> td = TensorDict(observation=torch.randn(4, 3), action=torch.randn(4, 2),
            ...                 batch_size=[4])
            >>> loss.advantage_weights(td)  # exp(2 · (1.0 − 0.5)) = e
            tensor([2.7183, 2.7183, 2.7183, 2.7183])
        """
        q = self.q_value(tensordict)
        v = self._evaluate(
            self.value_network, self.value_params, tensordict, self.tensor_keys.value
        ).squeeze(-1)
        weights = torch.exp(self.temperature * (q - v)).clamp_max(self.max_weight)
        if self.check_finite:
            require_finite(weights, "one of WeightedMAPActorLoss's advantage weights", tensordict)
        return weights

    # ------------------------------------------------------------------ loss
    def reset_parameters_recursive(self) -> None:
        """Re-initialises the actor, the one module this loss owns.

        The critic it reads belongs to the critic's loss.
        """
        with self.actor_params.to_module(self.actor):
            self.actor.reset_parameters_recursive()

    def _inputs(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        values = []
        dtype = self.actor.log_std.dtype
        for role, dim in (("observation", None), ("action", self.actor.action_dim)):
            value = read_loss_input(tensordict, getattr(self.tensor_keys, role), role)
            if dim is not None and value.shape[-1] != dim:
                raise ValueError(f"{role} must end with dim {dim}, got shape {tuple(value.shape)}.")
            if value.dtype != dtype:
                raise TypeError(
                    f"the batch's {role} is {value.dtype} and the actor's weights {dtype}: "
                    f"cast one to the other (batch.to({dtype}) or loss.to({value.dtype}))."
                )
            if self.check_finite:
                check_finite(value, role, "clean the batch first.")
            values.append(value)
        return values[0], values[1]

    def actor_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Per-sample loss of Eq. (7) for the configured weighting, and diagnostics."""
        observation, action = self._inputs(tensordict)
        with self.actor_params.to_module(self.actor):
            loc = self.actor(observation)
            std = self.actor.std.expand_as(loc)
            if self.weighting == "sac":  # the executed action: a clamped draw, its score
                executed = self.action_box.distribution(loc, std)
                sample = executed.rsample()
                log_prob = executed.log_prob(sample)
                td = tensordict.select(*self.qvalue_network.in_keys, strict=False).clone(False)
                td.set(self.tensor_keys.action, sample)
                loss = self.entropy_coef * log_prob - self.q_value(td)
                weight = torch.ones_like(log_prob)
            else:
                log_prob = Normal(loc, std).log_prob(action).sum(-1)
                if self.weighting == "advantage":
                    weight = self.advantage_weights(tensordict)
                else:
                    weight = torch.ones_like(log_prob)
                loss = -weight * log_prob
        metadata = {
            "weight_mean": weight.mean().detach(),
            "log_prob": log_prob.mean().detach(),
            "actor_std": self.actor.std.mean().detach(),
            "_weight": weight.detach(),
        }
        return loss, metadata

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """The reduced loss of Eq. (7); writes the per-sample weights ``w_i`` under ``weight``.

        Args:
            tensordict (TensorDictBase): transitions ``[*B]`` with the observation and the
                action (and what the critics read).

        Returns:
            ``loss_actor`` (a scalar, or ``[*B]`` under ``reduction="none"``) and the detached
            metrics ``weight_mean``, ``log_prob`` and ``actor_std``.
        """
        loss, metadata = self.actor_loss(tensordict)
        weight = metadata.pop("_weight")
        tensordict.set(self.tensor_keys.weight, weight)
        loss = self._reduce_loss(loss, tensordict=tensordict)
        return TensorDict({"loss_actor": loss, **metadata}, batch_size=[])
