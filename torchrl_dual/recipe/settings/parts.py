"""The schema of the parts several algorithms share.

The critics (the ``critic`` group and :data:`CRITICS`), planner augmentation (``augment``)
and the planner's window.

Builders are :class:`~torchrl_dual.recipe.settings.lazy.Ref` s into
:mod:`torchrl_dual.recipe.parts`, imported when a run starts.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.lazy import Ref
from torchrl_dual.recipe.settings.names import PENALTY_LAYOUTS, TARGET_REDUCTIONS, WEIGHTINGS
from torchrl_dual.recipe.settings.rules import Choice, Integer, Maybe, Real, Text, key


@dataclass
class CriticSettings:
    """The ``critic.*`` keys every critic has (its networks, optimizer and targets)."""

    name: str = key(Text(), "the CRITICS entry")
    hidden: int = key(Integer(1), "MLP width of the critic networks")
    depth: int = key(Integer(1), "hidden layers of the critic networks")
    lr: float = key(Real(0, low_open=True), "Adam learning rate of the critic networks")
    discount: float = key(Real(0, 1, low_open=True), "γ")
    target_update_tau: float = key(Real(0, 1, low_open=True), "soft target update rate")
    actor_weighting: str = key(Choice(WEIGHTINGS), "preset of DUAL's actor.weighting")


@dataclass
class IQLCriticSettings(CriticSettings):
    """``critic/iql.yaml``: TorchRL ``IQLLoss`` expectile value network and twin Q networks."""

    expectile: float = key(Real(0, 1, low_open=True, high_open=True), "IQL expectile τ")


BELLMAN_LOSSES = ("l2", "smooth_l1")
"""``critic.bellman_loss`` of Cal-QL: the squared error of the Cal-QL, CQL, CORL and d3rlpy
code (default) or TorchRL ``CQLLoss``'s default ``smooth_l1``, whose gradient is capped at 1
per transition."""


@dataclass
class CalQLCriticSettings(CriticSettings):
    """``critic/calql.yaml``: Cal-QL's twin Q networks (TorchRL ``CQLLoss`` + MC bound).

    ``discount`` is also the bound's.
    """

    min_q_weight: float = key(Real(0), "weight of the conservative penalty")
    num_random: int = key(Integer(1), "uniform and policy actions per state in the penalty")
    temperature: float = key(Real(0, low_open=True), "temperature of the penalty's logsumexp")
    penalty_layout: str = key(Choice(PENALTY_LAYOUTS), "logsumexp grouping (CalQLLoss)")
    sparse_failure_reward: Any = key(
        Maybe(Real()), "r_fail of Cal-QL's sparse-reward bound r_fail / (1 - γ); null: off"
    )
    lagrange_gap: Any = key(
        Maybe(Real()),
        "target gap τ of the penalty's Lagrange multiplier (Cal-QL AntMaze: 0.8); null: a fixed weight",
    )
    bellman_loss: str = key(
        Choice(BELLMAN_LOSSES),
        "loss of each Q network's TD error: l2 (the references') or smooth_l1 (CQLLoss's default)",
    )


@dataclass
class SO2CriticSettings(CriticSettings):
    """``critic/so2.yaml``: SO2's Q ensemble (:class:`~torchrl_dual.objectives.SO2QLoss`).

    Offline it is SAC-N (the target is the ensemble's minimum, no smoothing noise, one
    critic step per update); online, SO2's changes: each member's own target at the
    noise-smoothed next action, ``online_steps_per_update`` critic steps per update.
    """

    num_qvalue_nets: int = key(Integer(1), "ensemble size E (SO2: 10)")
    policy_noise: float = key(Real(0), "σ of the target action's smoothing noise (online)")
    noise_clip: float = key(Real(0), "c: the smoothing noise is clipped to [-c, c]")
    target_reduction: str = key(Choice(TARGET_REDUCTIONS), "online targets per member or reduced")
    offline_target_reduction: str = key(Choice(TARGET_REDUCTIONS), "offline (SAC-N: min)")
    entropy_coef: float = key(Real(0), "α of the targets' and the SAC actor's entropy term")
    online_steps_per_update: int = key(Integer(1), "critic steps per update online (SO2: 10)")


POLICY_CRITICS = ("calql", "so2")
"""Critics whose loss samples the policy: a learner with its own actor passes them
:func:`policy_view` of it (``actor=``)."""


class CriticKind(NamedTuple):
    """One ``critic.name``: its schema and its builder."""

    settings: type
    """The dataclass of ``critic.*`` (checked by ``validate_config``)."""
    make: Callable[..., Any]
    """``(settings, obs_dim, action_dim, device="cpu", actor=None, temperature=1.0) ->``
    :class:`~torchrl_dual.recipe.parts.critics.Critic`, ``settings`` an instance of
    :attr:`settings` (:func:`~torchrl_dual.recipe.parts.critics.make_critic` builds it
    from the config)."""


_CRITICS = "torchrl_dual.recipe.parts.critics"

CRITICS: dict[str, CriticKind] = {
    "iql": CriticKind(IQLCriticSettings, Ref(f"{_CRITICS}:make_iql_critic")),
    "calql": CriticKind(CalQLCriticSettings, Ref(f"{_CRITICS}:make_calql_critic")),
    "so2": CriticKind(SO2CriticSettings, Ref(f"{_CRITICS}:make_so2_critic")),
}
"""``critic.name`` -> its :class:`CriticKind`."""


AUGMENT_KINDS = ("none", "planner")
"""``augment.kind``: no augmentation, or guided planner windows (EDIS)."""


@dataclass
class AugmentSettings:
    """``augment``: planner data augmentation (EDIS, Algorithm 1 line 14)."""

    kind: str = key(Choice(AUGMENT_KINDS), "none | planner (guided planner transitions)")
    every: int = key(Integer(1), "online updates between augmentation rounds")
    num_windows: int = key(Integer(1), "windows generated per round (H transitions each)")
    guidance_scale: float = key(Real(0), "scale of the classifier guidance; 0 = unguided")
    guider_updates: int = key(Integer(0), "classifier updates per round")
    reward_updates: int = key(Integer(0), "reward-model updates per round")
    hidden: int = key(Integer(1), "width of the classifier and the reward model")
    lr: float = key(Real(0, low_open=True), "Adam learning rate of both")
    batch_size: int = key(Integer(1), "offline and online windows (transitions) per update")


def online_updates(cfg: DictConfig) -> int:
    """The online phase's gradient updates (at most): ``online.utd_ratio × online_frames``."""
    return math.ceil(cfg.online.utd_ratio * cfg.budget.online_frames)


def check_augment(cfg: DictConfig) -> None:
    """``augment.kind=planner`` needs a multi-step DDPM teacher and at least one round."""
    a = cfg.augment
    if a.kind == "none":
        return
    if cfg.planner.num_steps < 2:
        raise ConfigError(
            "planner.num_steps",
            cfg.planner.num_steps,
            "must be >= 2 with augment.kind=planner: the guidance shifts the means of the "
            "teacher's DDPM steps",
        )
    updates = online_updates(cfg)
    if 0 < updates < a.every:
        raise ConfigError(
            "augment.every",
            a.every,
            f"exceeds the online phase's {updates} updates (online.utd_ratio x "
            "budget.online_frames): no augmentation round would run; lower augment.every "
            "or use augment.kind=none",
        )


def check_planner_window(cfg: DictConfig) -> None:
    """Checks that the planner's window fits in an episode.

    A null time limit is the data set's, checked against its episodes when the windows
    are cut.
    """
    limit = cfg.env.max_episode_steps
    if limit is not None and cfg.planner.horizon >= limit:
        raise ConfigError(
            "planner.horizon",
            cfg.planner.horizon,
            f"must be < env.max_episode_steps={cfg.env.max_episode_steps} (a window holds "
            "horizon + 1 steps of one episode)",
        )
