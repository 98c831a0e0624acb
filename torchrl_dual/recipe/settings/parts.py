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

    name: str = key(
        Text(),
        "the `CRITICS` entry the recipe builds, chosen with `critic=<name>` (default `iql`): "
        "`iql` (TorchRL `IQLLoss`'s expectile value network and twin Q networks; every "
        "algorithm but `calql` and `so2` uses it), `calql` (Cal-QL's twin Q networks), `so2` "
        "(SO2's Q ensemble); `algo=calql` and `algo=so2` select theirs, and DUAL takes each "
        "(`algo=dual critic=calql`, `algo=dual critic=so2`)",
    )
    hidden: int = key(
        Integer(1),
        "MLP width of the critic networks: `V` and `Q` (`iql`), `Q` (`calql`), each ensemble "
        "member (`so2`)",
    )
    depth: int = key(
        Integer(1),
        "hidden layers of each critic network; `calql`: Cal-QL's 256 × 2, its reference's 4 "
        "on AntMaze and 3 on Adroit (the [reference presets](recipe.md#env), "
        "`settings/references.py`); `so2`: SO2's 256 × 2",
    )
    lr: float = key(
        Real(0, low_open=True),
        "Adam learning rate of the critic networks (`so2`: of the whole ensemble)",
    )
    discount: float = key(
        Real(0, 1, low_open=True), "`γ` of the TD target (`calql`: also of the Monte-Carlo bound)"
    )
    target_update_tau: float = key(
        Real(0, 1, low_open=True),
        "soft update rate of the target Q networks (`so2`: of the target ensemble)",
    )
    actor_weighting: str = key(
        Choice(WEIGHTINGS),
        "preset of DUAL's `actor.weighting` on this critic: `advantage` for `iql` (Eq. 7's "
        "`exp(β (Q − V))`), `sac` for `calql` and `so2` (`Q − α log π`: they have no V, so "
        "`advantage` is refused with them)",
    )


@dataclass
class IQLCriticSettings(CriticSettings):
    """``critic/iql.yaml``: TorchRL ``IQLLoss`` expectile value network and twin Q networks."""

    expectile: float = key(
        Real(0, 1, low_open=True, high_open=True),
        "IQL expectile `τ`: the env family's preset `env.critic_expectile` (CORL's IQL: 0.7 on "
        "maze2d and locomotion, 0.9 on AntMaze, 0.8 on Adroit)",
    )


BELLMAN_LOSSES = ("l2", "smooth_l1")
"""``critic.bellman_loss`` of Cal-QL: the squared error of the Cal-QL, CQL, CORL and d3rlpy
code (default) or TorchRL ``CQLLoss``'s default ``smooth_l1``, whose gradient is capped at 1
per transition."""


@dataclass
class CalQLCriticSettings(CriticSettings):
    """``critic/calql.yaml``: Cal-QL's twin Q networks (TorchRL ``CQLLoss`` + MC bound).

    ``discount`` is also the bound's.
    """

    min_q_weight: float = key(
        Real(0),
        "weight of the conservative penalty (Cal-QL's `cql_min_q_weight`: 5, 1 on Adroit, the "
        "[reference presets](recipe.md#env)); with `lagrange_gap` the multiplier's initial "
        "value is `exp(1)` instead and this key is unused",
    )
    num_random: int = key(
        Integer(1), "uniform and policy actions per state in the penalty (Cal-QL: 10)"
    )
    temperature: float = key(Real(0, low_open=True), "temperature of the penalty's logsumexp")
    penalty_layout: str = key(
        Choice(PENALTY_LAYOUTS),
        "grouping of the penalty's logsumexp: `calql`, the reference code's; `torchrl`, "
        "`CQLLoss`'s",
    )
    sparse_failure_reward: Any = key(
        Maybe(Real()),
        "`r_fail` of Cal-QL's sparse-reward bound: an episode that never left it is worth "
        "`r_fail / (1 − γ)` (AntMaze with rewards `10 r − 5`: `-5`, the "
        "[reference preset](recipe.md#env)); `null`: off",
    )
    lagrange_gap: Any = key(
        Maybe(Real()),
        "`τ` of Cal-QL's Lagrange form (`cql_lagrange`, `cql_target_action_gap`; AntMaze: 0.8, "
        "the [reference preset](recipe.md#env)): the penalty weight becomes a learned "
        "`α' = exp(log α')` (clamped to [0, 10⁶]) that rises while the policy-minus-data Q gap "
        "exceeds `τ` and falls below it; `log α'` joins the critic's optimizer and "
        "`loss_alpha_prime` the update (`CalQLLoss(with_lagrange=True, lagrange_thresh=τ)`). "
        "`null`: the fixed weight `min_q_weight`",
    )
    bellman_loss: str = key(
        Choice(BELLMAN_LOSSES),
        "the loss of each Q network's TD error: `l2`, the squared error of the Cal-QL, CQL, "
        "CORL and d3rlpy code, or `smooth_l1`, TorchRL `CQLLoss`'s default, whose gradient is "
        "capped at 1 per transition (with AntMaze's rewards `10 r − 5` the Q-values reach 500 "
        "in magnitude and the Q networks then learn far slower)",
    )


@dataclass
class SO2CriticSettings(CriticSettings):
    """``critic/so2.yaml``: SO2's Q ensemble (:class:`~torchrl_dual.objectives.SO2QLoss`).

    Offline it is SAC-N (the target is the ensemble's minimum, no smoothing noise, one
    critic step per update); online, SO2's changes: each member's own target at the
    noise-smoothed next action, ``online_steps_per_update`` critic steps per update.
    """

    num_qvalue_nets: int = key(Integer(1), "ensemble size `E` (SO2: 10; 50 on Hopper)")
    policy_noise: float = key(
        Real(0), "`σ` of the Gaussian smoothing noise on the online target action (SO2: 0.3)"
    )
    noise_clip: float = key(Real(0), "`c`: the smoothing noise is clipped to `[-c, c]` (SO2: 0.6)")
    target_reduction: str = key(
        Choice(TARGET_REDUCTIONS),
        "online targets: `independent` (each member regresses on its own, SO2's code), or the "
        "ensemble's `min` or `mean`",
    )
    offline_target_reduction: str = key(
        Choice(TARGET_REDUCTIONS),
        "offline targets, as `target_reduction` (SAC-N: `min`, the ensemble's minimum at the "
        "actor's unperturbed next action)",
    )
    entropy_coef: float = key(
        Real(0),
        "`α` of the targets' entropy term `− α log π` at the next action, of the SO2 baseline's "
        "SAC actor loss and of DUAL's `sac` weighting on this critic (SO2: a fixed 0.2)",
    )
    online_steps_per_update: int = key(
        Integer(1),
        "critic steps (each on its own batch) per actor step online; × `online.utd_ratio` = "
        "critic updates per frame (SO2: 10 × 1)",
    )


class CriticKind(NamedTuple):
    """One ``critic.name``: its schema, its builder and what it asks of the run."""

    settings: type
    """The dataclass of ``critic.*`` (checked by ``validate_config``)."""
    make: Callable[..., Any]
    """``(settings, obs_dim, action_dim, device="cpu", actor=None, temperature=1.0) ->``
    :class:`~torchrl_dual.recipe.parts.critics.Critic`, ``settings`` an instance of
    :attr:`settings` (:func:`~torchrl_dual.recipe.parts.critics.make_critic` builds it
    from the config)."""
    has_value: bool = False
    """Whether it learns ``V(s)``, which Eq. 7's ``actor.weighting=advantage`` reads."""
    samples_policy: bool = False
    """Whether its loss samples the policy: a learner with its own actor passes it
    :func:`~torchrl_dual.recipe.parts.networks.policy_view` of it (``actor=``)."""
    monte_carlo_labels: bool = False
    """Whether its loss reads Monte-Carlo returns: whole online episodes from one stream,
    no generated transitions (``augment``)."""


_CRITICS = "torchrl_dual.recipe.parts.critics"

CRITICS: dict[str, CriticKind] = {
    "iql": CriticKind(IQLCriticSettings, Ref(f"{_CRITICS}:make_iql_critic"), has_value=True),
    "calql": CriticKind(
        CalQLCriticSettings,
        Ref(f"{_CRITICS}:make_calql_critic"),
        samples_policy=True,
        monte_carlo_labels=True,
    ),
    "so2": CriticKind(SO2CriticSettings, Ref(f"{_CRITICS}:make_so2_critic"), samples_policy=True),
}
"""``critic.name`` -> its :class:`CriticKind`."""


AUGMENT_KINDS = ("none", "planner")
"""``augment.kind``: no augmentation, or guided planner windows (EDIS)."""


@dataclass
class AugmentSettings:
    """``augment``: planner data augmentation (EDIS, Algorithm 1 line 14)."""

    kind: str = key(
        Choice(AUGMENT_KINDS),
        "`none`, or `planner`: guided planner transitions are added to the online replay "
        "buffer every `every` online updates (needs `planner.num_steps` ≥ 2). With `algo=dual`, "
        "`planner` is DUAL + EDIS (guiding DUAL's trained teacher); `algo=edis` requires "
        "`planner` (IQL alone is `algo=iql`); `critic=calql` refuses `planner`. What a round "
        "does: "
        "[EDIS](recipe.md#edis-baseline-and-planner-augmentation-algoedis-augmentkindplanner)",
    )
    every: int = key(
        Integer(1),
        "online updates between augmentation rounds (Algorithm 1's update frequency, which also "
        "paces the Laplace refits); must not exceed the online phase's "
        "`online.utd_ratio × budget.online_frames` updates",
    )
    num_windows: int = key(
        Integer(1),
        "guided windows generated per round, `H` transitions each (250 × 8 = the 2000 frames "
        "collected between two rounds at the default budget)",
    )
    guidance_scale: float = key(
        Real(0),
        "`s` of the classifier guidance's mean shift `s·Σ·∇ log-ratio` at each DDPM step; `0` "
        "samples the unguided planner",
    )
    guider_updates: int = key(
        Integer(0),
        "updates of the energy guider (a classifier of noisy offline vs online windows) per round",
    )
    reward_updates: int = key(
        Integer(0), "updates of the reward model that labels the generated transitions, per round"
    )
    hidden: int = key(Integer(1), "width of the energy guider and the reward model")
    lr: float = key(Real(0, low_open=True), "Adam learning rate of the guider and reward model")
    batch_size: int = key(
        Integer(1),
        "offline windows and as many online windows per guider update; transitions per "
        "reward-model update, as many from each",
    )


def online_updates(cfg: Any) -> int:
    """The online phase's gradient updates (at most): ``online.utd_ratio × online_frames``.

    ``cfg``: the config, or the run's typed
    :class:`~torchrl_dual.recipe.settings.structured.RecipeSettings`.
    """
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
