"""SO2's ensemble critic loss.

Zhang et al. 2024, "A Perspective of Q-value Estimation on Offline-to-Online Reinforcement
Learning", arXiv:2312.07685.

SO2 fine-tunes an offline-pretrained Q ensemble (SAC-N / EDAC) online with two changes:

1. *Perturbed value update*: the target action is smoothed as in TD3's target policy
   smoothing (Fujimoto et al. 2018), ``ã' = clip(a' + clip(σ·ε, −c, c), low, high)`` with
   ``a' ∼ π(·|s')`` and ``ε ∼ N(0, I)``, one ``ã'`` per transition shared by all members;
2. *more frequent Q updates* (10 critic updates per environment step, one actor update
   per 10 critic updates): the training loop's business, not the loss's.

Facts from the authors' code (``opendilab/SO2``, ``ding/policy/edac.py``, ``train.py``),
which this loss follows by default:

* each member regresses on its *own* target, ``y_k = r + γ·(1 − terminated)·(Q̄_k(s', ã')
  − α·log π(a'|s'))`` (no min or mean over the ensemble; ``target_reduction="min"`` and
  ``"mean"`` are offered as variants), and the loss is the squared error averaged over
  members and batch;
* the actor is SAC's tanh-Gaussian: ``a'`` is a *sample* (``next_action="sample"``), the
  entropy bonus uses the log-probability of the sample before the noise, with a fixed
  ``α = 0.2`` (``entropy_coef``; 0 for a deterministic actor); timeouts are not terminal;
* ``E = 10`` members (50 on Hopper), ``σ = 0.3``, ``c = 0.6``, actions in ``[−1, 1]``,
  ``γ = 0.99``, soft target updates with ``τ = 0.005`` (TorchRL's
  :class:`~torchrl.objectives.SoftUpdate`), and the actor maximises
  ``min_k Q_k(s, a) − α·log π(a|s)`` (:meth:`SO2QLoss.q_value`).

The ensemble is one functional module with stacked parameters
(``convert_to_functional(..., expand_dim=E)``, as TorchRL's ``REDQLoss``), evaluated with
``torch.vmap`` over the members.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase, TensorDictParams
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torchrl.data import Bounded, Composite, TensorSpec
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives.common import LossModule
from torchrl.objectives.utils import ValueEstimators, _vmap_func, distance_loss

from torchrl_dual._utils import read_key, read_loss_input

TARGET_REDUCTIONS = ("independent", "min", "mean")
NEXT_ACTIONS = ("sample", "mean")
ACTOR_REDUCTIONS = ("min", "mean")


class SO2QLoss(LossModule):
    """The critic loss of SO2: a Q ensemble trained on policy-smoothed targets.

    Steps of :meth:`qvalue_loss` on a batch ``(s, a, r, s', terminated)``:

    1. ``a'`` from the actor at ``s'`` (a sample or the mean, ``next_action``), with weights
       read detached: the critic loss never trains the actor;
    2. ``ã' = clip(a' + clip(σ·ε, −c, c), low, high)`` (:meth:`target_action`);
    3. ``V(s') = Q̄(s', ã') − α·log π(a'|s')`` with the target ensemble ``Q̄`` (per member,
       or its min or mean: ``target_reduction``) and ``y = r + γ·(1 − terminated)·V(s')``;
    4. ``L = mean_k mean_b ℓ(Q_k(s, a), y_k)`` with ``ℓ`` the ``loss_function``.

    ======================  ====================================
    entry                   shape
    ======================  ====================================
    observation, action     ``[B, obs_dim]``, ``[B, act_dim]``
    next reward/terminated  ``[B, 1]``
    target value ``y``      ``[E, B]`` (``independent``) or ``[B]``
    ``Q_k(s, a)``           ``[E, B]``
    ======================  ====================================

    Args:
        actor_network (TensorDictModuleBase): any TorchRL actor reading the observation and
            writing ``tensor_keys.action`` (and ``tensor_keys.log_prob`` if
            ``entropy_coef > 0``, e.g. a ``ProbabilisticActor`` with ``return_log_prob``).
            Not registered here: its weights belong to the actor's loss and optimizer.
        qvalue_network (TensorDictModuleBase): one member, writing
            ``tensor_keys.state_action_value`` ``[B, 1]`` from observation and action; it is
            copied into ``num_qvalue_nets`` independently initialised members.

    Keyword Args:
        action_spec (TensorSpec): the bounded action spec (or a ``Composite`` holding it
            under ``tensor_keys.action``); its box clips ``ã'``.
        num_qvalue_nets (int): ensemble size ``E``. Defaults to ``10``.
        policy_noise (float): ``σ`` of the target smoothing noise. Defaults to ``0.3``.
        noise_clip (float): ``c``, the noise is clipped to ``[−c, c]``. Defaults to ``0.6``.
        target_reduction (str): one of :data:`TARGET_REDUCTIONS`. Defaults to
            ``"independent"`` (SO2's code).
        next_action (str): ``"sample"`` (SO2's SAC actor, ``ExplorationType.RANDOM``) or
            ``"mean"`` (``ExplorationType.DETERMINISTIC``, TD3). Defaults to ``"sample"``.
        entropy_coef (float): ``α``; SO2 uses ``0.2`` with its SAC actor. Defaults to ``0.0``.
        gamma (float): discount ``γ``. Defaults to ``0.99``.
        loss_function (str): ``"l2"``, ``"l1"`` or ``"smooth_l1"``. Defaults to ``"l2"``.
        reduction (str): ``"none"`` | ``"mean"`` | ``"sum"``. Defaults to ``"mean"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from tensordict.nn import TensorDictModule
        >>> from torchrl.data import Bounded
        >>> from torchrl.modules import MLP, ValueOperator
        >>> from torchrl.objectives import SoftUpdate
        >>> _ = torch.manual_seed(0)
        >>> actor = TensorDictModule(MLP(in_features=3, out_features=2, num_cells=[16]),
        ...                          in_keys=["observation"], out_keys=["action"])
        >>> qvalue = ValueOperator(MLP(in_features=5, out_features=1, num_cells=[16]),
        ...                        in_keys=["observation", "action"])
        >>> loss = SO2QLoss(actor, qvalue, action_spec=Bounded(-1, 1, shape=(2,)),
        ...                 num_qvalue_nets=4)
        >>> updater = SoftUpdate(loss, tau=0.005)
        >>> batch = TensorDict({"observation": torch.randn(8, 3), "action": torch.rand(8, 2),
        ...     "next": {"observation": torch.randn(8, 3), "reward": torch.randn(8, 1),
        ...              "terminated": torch.zeros(8, 1, dtype=torch.bool)}}, [8])
        >>> out = loss(batch)
        >>> out["loss_qvalue"].backward()
        >>> updater.step()
        >>> loss.q_value(batch["observation"], batch["action"]).shape  # min over members
        torch.Size([8])
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys.

        Attributes:
            observation (NestedKey): the state, read by :meth:`q_value`.
                Defaults to ``"observation"``.
            action (NestedKey): the action. Defaults to ``"action"``.
            state_action_value (NestedKey): the Q network's output.
                Defaults to ``"state_action_value"``.
            log_prob (NestedKey): the actor's log-probability of its action, read when
                ``entropy_coef > 0``. Defaults to ``"action_log_prob"``.
            reward (NestedKey): under ``"next"``. Defaults to ``"reward"``.
            terminated (NestedKey): under ``"next"``; truncation is not terminal.
                Defaults to ``"terminated"``.
        """

        observation: NestedKey = "observation"
        action: NestedKey = "action"
        state_action_value: NestedKey = "state_action_value"
        log_prob: NestedKey = "action_log_prob"
        reward: NestedKey = "reward"
        terminated: NestedKey = "terminated"

    default_keys = _AcceptedKeys
    out_keys = ["loss_qvalue", "state_action_value", "target_value"]

    qvalue_network: TensorDictModuleBase
    qvalue_network_params: TensorDictParams
    target_qvalue_network_params: TensorDictParams

    def __init__(
        self,
        actor_network: TensorDictModuleBase,
        qvalue_network: TensorDictModuleBase,
        *,
        action_spec: TensorSpec,
        num_qvalue_nets: int = 10,
        policy_noise: float = 0.3,
        noise_clip: float = 0.6,
        target_reduction: str = "independent",
        next_action: str = "sample",
        entropy_coef: float = 0.0,
        gamma: float = 0.99,
        loss_function: str = "l2",
        reduction: str = "mean",
    ) -> None:
        super().__init__()
        for name, value, options in (
            ("target_reduction", target_reduction, TARGET_REDUCTIONS),
            ("next_action", next_action, NEXT_ACTIONS),
            ("loss_function", loss_function, ("l2", "l1", "smooth_l1")),
        ):
            if value not in options:
                raise ValueError(f"Unknown {name} {value!r}; choose one of {options}.")
        if num_qvalue_nets < 1:
            raise ValueError(f"num_qvalue_nets must be >= 1, got {num_qvalue_nets}.")
        if policy_noise < 0 or noise_clip < 0:
            raise ValueError(
                f"policy_noise and noise_clip must be >= 0, got {policy_noise} and {noise_clip}."
            )
        # The actor belongs to the actor's loss: kept unregistered so the critic's
        # optimizer and state_dict never see it.
        self.__dict__["actor_network"] = actor_network
        self.convert_to_functional(
            qvalue_network, "qvalue_network", num_qvalue_nets, create_target_params=True
        )
        self.num_qvalue_nets = num_qvalue_nets
        if isinstance(action_spec, Composite):
            action_spec = action_spec[self.tensor_keys.action]
        if not isinstance(action_spec, Bounded):
            raise ValueError(
                "SO2QLoss clips the smoothed action to the action box and needs a bounded "
                f"action_spec (torchrl.data.Bounded); got {type(action_spec).__name__}."
            )
        low, high = action_spec.space.low, action_spec.space.high
        self.register_buffer("action_low", torch.as_tensor(low).clone())
        self.register_buffer("action_high", torch.as_tensor(high).clone())
        self.policy_noise, self.noise_clip = policy_noise, noise_clip
        self.target_reduction, self.next_action = target_reduction, next_action
        self.entropy_coef, self.gamma = entropy_coef, gamma
        self.loss_function, self.reduction = loss_function, reduction
        self._make_vmap()

    def _make_vmap(self) -> None:
        """The ensemble's ``vmap`` over the members, with TorchRL's ``vmap_randomness``.

        ``"different"`` when the Q network holds a random module such as dropout.
        """
        self._ensemble = _vmap_func(self.qvalue_network, (None, 0), randomness=self.vmap_randomness)

    def reset_parameters_recursive(self) -> None:
        """Re-initialises the Q ensemble and its target.

        The actor belongs to the actor's loss and is left as it is.
        """
        self._reset_module_parameters("qvalue_network", self.qvalue_network)

    def _forward_value_estimator_keys(self, **kwargs) -> None:
        pass

    def make_value_estimator(
        self, value_type: ValueEstimators | None = None, **hyperparams
    ) -> SO2QLoss:
        """TorchRL's ``make_value_estimator``, so that generic loops work; only TD(0).

        Generic loops call ``loss.make_value_estimator(gamma=0.99)``. SO2's target
        is the one-step (TD(0)) bootstrap ``r + γ (1 − terminated) V(s')`` over its
        smoothed, per-member ``V(s')``, so ``ValueEstimators.TD0`` (the default) is
        the only type and ``gamma`` its one hyperparameter.

        Examples:
            >>> import torch
            >>> from torchrl.data import Bounded
            >>> from torchrl.modules import MLP, ValueOperator
            >>> from torchrl_dual.modules import LinearHeadActor
            >>> q = ValueOperator(MLP(in_features=5, out_features=1, num_cells=[8]),
            ...                   in_keys=["observation", "action"])
            >>> actor = LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 2)
            >>> loss = SO2QLoss(actor, q, action_spec=Bounded(-1.0, 1.0, shape=(2,)))
            >>> loss.make_value_estimator(gamma=0.9).gamma
            0.9
        """
        if value_type not in (None, ValueEstimators.TD0):
            raise NotImplementedError(
                f"SO2QLoss bootstraps one step (TD0) over its ensemble; got {value_type}. "
                "Call make_value_estimator() or make_value_estimator(ValueEstimators.TD0)."
            )
        unknown = set(hyperparams) - {"gamma"}
        if unknown:
            raise TypeError(f"SO2QLoss's TD0 target takes gamma only, got {sorted(unknown)}.")
        if "gamma" in hyperparams:
            self.gamma = float(hyperparams["gamma"])
        return self

    @property
    def in_keys(self) -> list[NestedKey]:
        """The keys the loss reads: ``(s, a)``, the next states, the reward and ``terminated``."""
        action = self.tensor_keys.action
        states = [k for k in self.qvalue_network.in_keys if k != action]
        states = list(dict.fromkeys([*states, *self.actor_network.in_keys]))
        return [
            *dict.fromkeys([*self.qvalue_network.in_keys]),
            *(("next", k) for k in states),
            ("next", self.tensor_keys.reward),
            ("next", self.tensor_keys.terminated),
        ]

    # ------------------------------------------------------------------ ensemble
    def ensemble_values(self, tensordict: TensorDictBase, params: TensorDictBase) -> torch.Tensor:
        """``Q_k(s, a)`` of every member of ``params`` (stacked, leading ``E``), ``[E, *B]``."""
        td = tensordict.select(*self.qvalue_network.in_keys, strict=False)
        out = self._ensemble(td, params)
        return out.get(self.tensor_keys.state_action_value).squeeze(-1)

    def q_value(
        self, observation: torch.Tensor, action: torch.Tensor, *, reduction: str = "min"
    ) -> torch.Tensor:
        """The actor's objective ``min_k Q_k(s, a)`` (SO2; or the ``"mean"``), ``[*B]``.

        The critic's weights are read detached: gradients reach ``action`` (and through it
        the actor), never the ensemble.
        """
        if reduction not in ACTOR_REDUCTIONS:
            raise ValueError(f"Unknown reduction {reduction!r}; choose one of {ACTOR_REDUCTIONS}.")
        td = TensorDict(batch_size=observation.shape[:-1])
        td.set(self.tensor_keys.observation, observation)
        td.set(self.tensor_keys.action, action)
        values = self.ensemble_values(td, self.qvalue_network_params.detach())
        return values.min(0).values if reduction == "min" else values.mean(0)

    # ------------------------------------------------------------------ target
    @torch.no_grad()
    def target_action(self, next_tensordict: TensorDictBase) -> tuple[torch.Tensor, torch.Tensor]:
        """The smoothed next action ``ã'`` and the log-probability of the un-noised ``a'``.

        ``(ã', log π(a'|s'))``, the log-probability zeros when ``entropy_coef ==
        0``.
        """
        td = next_tensordict.select(*self.actor_network.in_keys, strict=False).clone(False)
        mode = (
            ExplorationType.RANDOM
            if self.next_action == "sample"
            else ExplorationType.DETERMINISTIC
        )
        with set_exploration_type(mode):
            td = self.actor_network(td)
        action = read_loss_input(td, self.tensor_keys.action, "action")
        if self.entropy_coef > 0:
            log_prob = read_key(
                td,
                self.tensor_keys.log_prob,
                "SO2QLoss's entropy term (entropy_coef > 0)",
                "Build the actor with return_log_prob=True, call loss.set_keys(log_prob=...) "
                "or set entropy_coef=0.",
            )
            log_prob = log_prob.reshape(action.shape[:-1])
        else:
            log_prob = torch.zeros(action.shape[:-1], device=action.device)
        noise = (torch.randn_like(action) * self.policy_noise).clamp(
            -self.noise_clip, self.noise_clip
        )
        smoothed = torch.maximum(torch.minimum(action + noise, self.action_high), self.action_low)
        return smoothed, log_prob

    @torch.no_grad()
    def target_value(self, tensordict: TensorDictBase) -> torch.Tensor:
        """The TD target ``y = r + γ·(1 − terminated)·(Q̄(s', ã') − α·log π(a'|s'))``.

        ``[E, *B]`` for ``target_reduction="independent"``, else ``[*B]``.
        """
        next_td = read_key(tensordict, "next", "SO2QLoss", "Add the next step under 'next'.")
        action, log_prob = self.target_action(next_td)
        next_td = next_td.select(*self.qvalue_network.in_keys, strict=False).clone(False)
        next_td.set(self.tensor_keys.action, action)
        next_q = self.ensemble_values(next_td, self.target_qvalue_network_params)
        if self.target_reduction == "min":
            next_q = next_q.min(0).values
        elif self.target_reduction == "mean":
            next_q = next_q.mean(0)
        next_value = next_q - self.entropy_coef * log_prob
        reward = read_loss_input(tensordict, ("next", self.tensor_keys.reward), "reward")
        terminated = read_loss_input(
            tensordict, ("next", self.tensor_keys.terminated), "terminated"
        )
        reward = reward.reshape(log_prob.shape)
        not_terminal = (~terminated.bool()).reshape(log_prob.shape).to(reward.dtype)
        return reward + self.gamma * not_terminal * next_value

    # ------------------------------------------------------------------ loss
    def qvalue_loss(self, tensordict: TensorDictBase) -> tuple[torch.Tensor, dict]:
        """Per-sample loss ``mean_k ℓ(Q_k(s, a), y_k)``, ``[*B]``, and diagnostics."""
        target = self.target_value(tensordict)
        q = self.ensemble_values(tensordict, self.qvalue_network_params)
        target = target.expand_as(q)
        loss = distance_loss(q, target, self.loss_function).mean(0)
        metadata = {
            "state_action_value": q.mean().detach(),
            "target_value": target.mean().detach(),
        }
        return loss, metadata

    critic_out_keys = ("loss_qvalue",)
    """The terms :meth:`critic_terms` returns (the critic protocol of ``DUALLoss``)."""

    def critic_terms(self, tensordict: TensorDictBase) -> dict[str, torch.Tensor]:
        """The loss of one critic step: the ensemble's TD loss ``loss_qvalue``, reduced."""
        loss = self._reduce_loss(self.qvalue_loss(tensordict)[0], tensordict=tensordict)
        return {"loss_qvalue": loss}

    def critic_parameters(self) -> list[torch.Tensor]:
        """What the critic's optimizer steps: the Q ensemble."""
        return list(self.qvalue_network_params.values(True, True))

    def forward(self, tensordict: TensorDictBase) -> TensorDict:
        """SO2's reduced critic loss and its diagnostics.

        Args:
            tensordict (TensorDictBase): transitions ``[*B]`` with ``next`` states, rewards and
                ``terminated`` flags.

        Returns:
            ``loss_qvalue`` and the detached means ``state_action_value`` and ``target_value``.
        """
        loss, metadata = self.qvalue_loss(tensordict)
        loss = self._reduce_loss(loss, tensordict=tensordict)
        return TensorDict({"loss_qvalue": loss, **metadata}, batch_size=[])
