"""The recipe's critics ``Q_φ`` and ``V`` (Alg. 1 lines 7 and 15): a table by ``critic.name``.

TorchRL's IQL critics (``critic/iql.yaml``, every algorithm), Cal-QL's
(``critic/calql.yaml``: :class:`~torchrl_dual.objectives.CalQLLoss`, TorchRL's ``CQLLoss``
with the Monte-Carlo bound; ``algo=calql`` and ``algo=dual``) and SO2's
(``critic/so2.yaml``: :class:`~torchrl_dual.objectives.SO2QLoss`, a Q ensemble on
policy-smoothed targets; ``algo=so2`` and ``algo=dual``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import Any

import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import TensorSpec
from torchrl.data.utils import DEVICE_TYPING
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator

from torchrl_dual.modules.actors.action_box import ClippedNormal, box_bounds
from torchrl_dual.objectives import (
    CalQLLoss,
    ForeachSoftUpdate,
    IQLCriticLoss,
    OnePassIQLLoss,
    SO2QLoss,
)
from torchrl_dual.objectives.optim import adam
from torchrl_dual.recipe.settings.parts import (
    CRITICS,
    CalQLCriticSettings,
    CriticSettings,
    IQLCriticSettings,
    SO2CriticSettings,
)
from torchrl_dual.recipe.settings.structured import RecipeSettings

CriticLoss = IQLCriticLoss | OnePassIQLLoss | CalQLLoss | SO2QLoss


@dataclass
class Critic:
    """A critic loss, the optimizer of its Q (and V) networks, and its target-network updater.

    The loss is TorchRL's ``IQLLoss``, :class:`~torchrl_dual.objectives.CalQLLoss` or
    :class:`~torchrl_dual.objectives.SO2QLoss`.
    """

    loss: CriticLoss
    optimizer: torch.optim.Optimizer
    target_updater: ForeachSoftUpdate

    saves_actor: bool = True
    """``False`` when the loss samples a :func:`policy_view` of the learner's actor, which
    the learner saves itself: the checkpoint then holds each weight once."""

    online_steps_per_update: int = 1
    """Critic steps per learner update online (SO2: 10, each on its own batch)."""

    phases: Callable[..., None] | None = None
    """``(loss, online=bool) -> None``: sets the loss's offline or online settings (SO2)."""

    @classmethod
    def around(
        cls,
        loss: CriticLoss,
        params: Iterable[torch.Tensor],
        settings: CriticSettings,
        **options: Any,
    ) -> Critic:
        """Every builder's tail: the critic's optimizer and soft target update around ``loss``.

        Adam over ``params`` at ``critic.lr`` and the soft target update at
        ``critic.target_update_tau`` (``options``: the fields after
        :attr:`target_updater`).
        """
        optimizer = adam(params, lr=settings.lr)
        updater = ForeachSoftUpdate(loss, tau=settings.target_update_tau)
        return cls(loss, optimizer, updater, **options)

    def modules(self) -> dict[str, Any]:
        """What a learner's checkpoint holds of the critics (:meth:`Learner.modules`).

        The loss (V, the Q and the target Q networks) and its optimizer.
        """
        return {
            "critic": _CriticState(self.loss, keep_actor=self.saves_actor),
            "critic_optimizer": self.optimizer,
        }

    def set_phase(self, online: bool) -> None:
        """The critic's offline or online settings (SO2's; the other critics have one)."""
        if self.phases is not None:
            self.phases(self.loss, online=online)


class _CriticState:
    """What a checkpoint holds of a critic loss: its ``state_dict``, without the actor's weights.

    The actor weights it samples are left out unless ``keep_actor`` (else the learner
    saves them as its actor's).
    """

    def __init__(self, loss: nn.Module, *, keep_actor: bool) -> None:
        self.loss, self.keep_actor = loss, keep_actor

    def state_dict(self) -> dict[str, Any]:
        state = self.loss.state_dict()
        return state if self.keep_actor else {k: v for k, v in state.items() if not _is_actor(k)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Loads ``state`` after checking its keys here.

        TorchRL 0.14's ``LossModule`` (its ``TensorDictParams``) reports a parameter
        key it does not have as matched and skips it, even with ``strict=True``,
        which would leave those networks as they were initialised without a word
        (``test_critic_checkpoint.py`` shows the upstream behaviour).
        """
        given = {k for k in state if self.keep_actor or not _is_actor(k)}
        expected = set(self.state_dict())
        if given != expected:
            missing, unexpected = sorted(expected - given), sorted(given - expected)
            raise RuntimeError(
                f"critic state does not fit: missing {missing[:5]}, unexpected {unexpected[:5]}"
            )
        self.loss.load_state_dict(state, strict=self.keep_actor)


def _is_actor(name: str) -> bool:
    return name.startswith(("actor_network_params", "target_actor_network_params"))


def make_critic(
    settings: RecipeSettings,
    obs_dim: int,
    action_dim: int,
    actor: ProbabilisticActor | None = None,
    temperature: float = 1.0,
) -> Critic:
    """The ``critic.name`` entry of :data:`~torchrl_dual.recipe.settings.parts.CRITICS`, built.

    Built from the run's typed ``critic`` section on ``settings.device`` (``actor`` and
    ``temperature`` as its builder takes them).
    """
    critic = settings.critic
    return CRITICS[critic.name].make(
        critic, obs_dim, action_dim, settings.device, actor, temperature
    )


def make_iql_critic(
    settings: IQLCriticSettings,
    obs_dim: int,
    action_dim: int,
    device: DEVICE_TYPING = "cpu",
    actor: ProbabilisticActor | None = None,
    temperature: float = 1.0,
) -> Critic:
    """IQL's expectile value network V and twin Q networks (TorchRL ``IQLLoss``).

    Built in a fixed order (Q MLP, V MLP, then ``IQLLoss``, which redraws the second Q
    network's weights) so a seed gives the same critics. Without ``actor`` the loss is
    :class:`~torchrl_dual.objectives.IQLCriticLoss` (DUAL trains its actor with Eq. 7);
    with one (the ``iql`` baseline), ``loss.actor_loss`` is IQL's advantage-weighted
    regression at ``temperature`` and ``loss`` holds the actor's weights, which the
    critic's optimizer leaves alone.
    """
    c = settings
    qvalue = q_network(c, obs_dim, action_dim)
    value = ValueOperator(
        MLP(
            in_features=obs_dim,
            out_features=1,
            num_cells=[c.hidden] * c.depth,
            activation_class=nn.ReLU,
        ),
        in_keys=["observation"],
    )
    if actor is None:  # DUAL, Diff-QL: the critic alone
        loss = IQLCriticLoss(
            qvalue, value, expectile=c.expectile, num_qvalue_nets=2, loss_function="l2"
        ).to(device)
    else:
        loss = OnePassIQLLoss(
            actor,
            qvalue,
            value,
            expectile=c.expectile,
            temperature=temperature,
            num_qvalue_nets=2,
            loss_function="l2",
        ).to(device)
    loss.make_value_estimator(gamma=c.discount)
    params = list(loss.qvalue_network_params.values(True, True)) + list(
        loss.value_network_params.values(True, True)
    )
    return Critic.around(loss, params, c)


def make_calql_critic(
    settings: CalQLCriticSettings,
    obs_dim: int,
    action_dim: int,
    device: DEVICE_TYPING = "cpu",
    actor: ProbabilisticActor | None = None,
    temperature: float = 1.0,
) -> Critic:
    """Cal-QL's twin Q networks in a :class:`~torchrl_dual.objectives.CalQLLoss` on ``actor``.

    ``actor`` is a TorchRL ``TanhNormal`` actor: the penalty and the SAC actor loss
    sample it; ``temperature`` is unused (Cal-QL's actor loss is SAC's, not AWR). The
    critic's optimizer holds the Q networks (and, with ``critic.lagrange_gap``, the
    penalty's ``log α'`` at the critic's learning rate, as Cal-QL's code); the learner
    steps the actor and ``log_alpha``.
    """
    if actor is None:
        raise ValueError("critic=calql needs the actor it samples (a TanhNormal actor).")
    c = settings
    qvalue = q_network(c, obs_dim, action_dim)
    loss = CalQLLoss(
        actor,
        qvalue,
        penalty_layout=c.penalty_layout,
        min_q_weight=c.min_q_weight,
        num_random=c.num_random,
        temperature=c.temperature,
        with_lagrange=c.lagrange_gap is not None,
        lagrange_thresh=0.0 if c.lagrange_gap is None else c.lagrange_gap,
        loss_function=c.bellman_loss,
        action_spec=actor.spec,
    ).to(device)
    loss.make_value_estimator(gamma=c.discount)
    saves_actor = not any(isinstance(m, _MeanAndStd) for m in actor.modules())  # policy_view
    params = list(loss.qvalue_network_params.values(True, True))
    if loss.with_lagrange:
        params.append(loss.log_alpha_prime)
    return Critic.around(loss, params, c, saves_actor=saves_actor)


def make_so2_critic(
    settings: SO2CriticSettings,
    obs_dim: int,
    action_dim: int,
    device: DEVICE_TYPING = "cpu",
    actor: ProbabilisticActor | None = None,
    temperature: float = 1.0,
) -> Critic:
    """SO2's ensemble of Q networks in a :class:`~torchrl_dual.objectives.SO2QLoss`.

    ``critic.num_qvalue_nets`` networks, whose targets sample ``actor`` (with its
    log-probability: ``return_log_prob=True``); ``temperature`` is unused. Built in the
    offline (SAC-N) setting: :func:`so2_phase` switches to SO2's online one.
    """
    if actor is None:
        raise ValueError("critic=so2 needs the actor its targets sample.")
    c = settings
    loss = SO2QLoss(
        actor,
        q_network(c, obs_dim, action_dim),
        action_spec=actor.spec,
        num_qvalue_nets=c.num_qvalue_nets,
        policy_noise=c.policy_noise,
        noise_clip=c.noise_clip,
        target_reduction=c.offline_target_reduction,
        entropy_coef=c.entropy_coef,
        gamma=c.discount,
    ).to(device)
    phases = partial(so2_phase, settings=c)
    phases(loss, online=False)
    params = loss.qvalue_network_params.values(True, True)
    return Critic.around(
        loss, params, c, online_steps_per_update=c.online_steps_per_update, phases=phases
    )


def so2_phase(loss: SO2QLoss, *, settings: SO2CriticSettings, online: bool) -> None:
    """Switches SO2's critic between SAC-N's offline targets and SO2's online ones.

    Offline: SAC-N's targets (``critic.offline_target_reduction``, no noise); online:
    SO2's (``critic.target_reduction`` at the action smoothed by
    ``critic.policy_noise``).
    """
    c = settings
    loss.target_reduction = c.target_reduction if online else c.offline_target_reduction
    loss.policy_noise = c.policy_noise if online else 0.0


def q_network(settings: CriticSettings, obs_dim: int, action_dim: int) -> ValueOperator:
    """``Q(s, a)``: an MLP on the concatenated ``(s, a)``.

    ``critic.depth`` hidden layers of ``critic.hidden`` units (every critic's: IQL's
    twin, Cal-QL's twin, SO2's ensemble).
    """
    c = settings
    mlp = MLP(
        in_features=obs_dim + action_dim,
        out_features=1,
        num_cells=[c.hidden] * c.depth,
        activation_class=nn.ReLU,
    )
    return ValueOperator(mlp, in_keys=["observation", "action"])


class _MeanAndStd(nn.Module):
    """``observation -> (μ(s), σ̄)`` of a last-layer actor (DUAL's ``N(μ(s), σ̄²)``)."""

    def __init__(self, actor: nn.Module) -> None:
        super().__init__()
        self.actor = actor

    def forward(self, observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.actor(observation)
        return loc, self.actor.std.expand_as(loc)


def policy_view(actor: nn.Module, action_spec: TensorSpec) -> ProbabilisticActor:
    """A TorchRL ``ProbabilisticActor`` sampling ``N(μ(s), σ̄²)`` from DUAL's last-layer actor.

    The policy of Eq. 7's ``sac`` weighting, for a critic whose loss samples the policy
    (Cal-QL's penalty and target actions, SO2's target actions). Its draws are clamped
    to the action box (:class:`~torchrl_dual.modules.actors.action_box.ClippedNormal`):
    the critics read Q at the actions the env would execute, never at an extrapolation.
    It holds the actor's own parameters: the critic's optimizer never steps them and
    :meth:`Critic.modules` does not save them.
    """
    low, high = box_bounds(action_spec)
    return ProbabilisticActor(
        TensorDictModule(_MeanAndStd(actor), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=ClippedNormal,  # log π sums over the action dims
        distribution_kwargs={"low": low, "high": high},
        return_log_prob=True,  # SO2's targets read log π(a'|s')
    )
