"""DUAL's config sections (``algo/dual.yaml``), their checks across keys, and its entry.

The entry is in :data:`~torchrl_dual.recipe.ALGORITHMS`; the learner is
:class:`~torchrl_dual.recipe.algos.dual.DualLearner`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.algo_common import AlgorithmSettings, OnlineSettings
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.names import LATENTS, SCHEDULES, UNCERTAINTIES, WEIGHTINGS
from torchrl_dual.recipe.settings.parts import AugmentSettings, check_augment, check_planner_window
from torchrl_dual.recipe.settings.rules import (
    Choice,
    Either,
    Integer,
    PowerOfTwo,
    Real,
    as_settings,
    key,
)

TRANSITION_MODELS = ("frozen", "shared")
"""Where Eq. (10)'s ``ŝ_t`` comes from (``exploration.transition_model``)."""


ACTOR_INITS = ("distilled", "scratch")
"""What the actor starts from (``actor.init``): the distilled planner (DUAL) or its
architecture's fresh initialisation (the paper's "w/o planner" ablation)."""


@dataclass
class PlannerSettings:
    """Trajectory diffusion planner ``g_θ'`` (Eq. 3)."""

    horizon: int = key(Integer(1), "H: windows hold H + 1 state-action rows")
    num_steps: int = key(PowerOfTwo(), "N: sampling steps of the teacher")
    hidden: int = key(Integer(1), "residual-MLP denoiser width")
    depth: int = key(Integer(1), "residual blocks")
    schedule: str = key(Choice(SCHEDULES), "noise schedule")
    lr: float = key(Real(0, low_open=True), "Adam learning rate")
    batch_size: int = key(Integer(1), "windows per update")
    action_condition_prob: float = key(Real(0, 1), "how often a_0 is given")


@dataclass
class DistillationSettings:
    """Progressive distillation ``N -> 1`` (Salimans & Ho 2022)."""

    lr: float = key(Real(0, low_open=True), "Adam learning rate of every round")
    final_steps: int = key(
        PowerOfTwo(), "steps of the distilled actor; > 1 = the 'w/o distillation' ablation"
    )


@dataclass
class ActorSettings:
    """Weighted MAP actor (Eq. 7)."""

    weighting: str = key(Choice(WEIGHTINGS), "per-sample weights of Eq. 7")
    temperature: float = key(Real(0), "β of exp(β (Q - V))")
    max_weight: float = key(Real(0, low_open=True), "clip of the advantage weights")
    lr: float = key(Real(0, low_open=True), "Adam learning rate")
    init_std: float = key(Real(0, low_open=True), "initial σ̄")
    latent: str = key(Choice(LATENTS), "one-step planner latent")
    init: str = key(Choice(ACTOR_INITS), "distilled (DUAL) | scratch (the 'w/o planner' ablation)")


@dataclass
class EnsembleSettings:
    """The Laplace ensemble's keys of Eq. (8-9) that every algorithm acting with it has.

    ``dual``, ``iql_la``, ``diffql_la``: what
    :func:`~torchrl_dual.recipe.parts.networks.make_policy` reads.
    """

    num_samples: int = key(Integer(0), "M sub-policies; 0 = no epistemic UQ (MAP mean, σ̄)")
    prior_precision: Any = key(
        Either(
            (Choice(("evidence",)), Real(0, low_open=True)), "must be 'evidence' or a number > 0"
        ),
        "λ of the Gaussian prior",
    )
    posterior_temperature: Any = key(
        Either((Choice(("data",)), Real(0, low_open=True)), "must be 'data' or a number > 0"),
        "T: the posterior covariance × T (1: the summed loss); data: Eq. 7's mean loss",
    )


@dataclass
class LaplaceSettings(EnsembleSettings):
    """Last-layer Laplace ensemble (Eq. 8-9), DUAL's."""

    uq: str = key(Choice(UNCERTAINTIES), "laplace (Eq. 8) | latent (the 'w τ^N sampling' ablation)")


@dataclass
class ExplorationSettings:
    """Shift-aware exploration (Eq. 10)."""

    shift_weight: float = key(Real(0), "λ of the shift-aware variance")
    shift_floor: Any = key(
        Either((Choice(("offline",)), Real(0)), "must be 'offline' or a number >= 0"),
        "d_0 of λ max(d_t − d_0, 0); 0 = Eq. 10",
    )
    extra_variance: float = key(
        Real(0), "v_c added to every action's variance; 0 = Eq. 10 (λ = 0 and v_c > 0: its control)"
    )
    transition_model: str = key(Choice(TRANSITION_MODELS), "where ŝ_t comes from")


def check_dual(cfg: DictConfig) -> None:
    """DUAL's checks across keys, each naming the key at fault and what would fit."""
    p, budget, final_steps = cfg.planner, cfg.budget, cfg.distillation.final_steps
    if final_steps > p.num_steps:
        raise ConfigError(
            "distillation.final_steps",
            final_steps,
            f"must be <= planner.num_steps={p.num_steps} (distillation halves the steps)",
        )
    rounds = int(math.log2(p.num_steps // final_steps))
    if len(budget.distill_updates) != rounds:
        raise ConfigError(
            "budget.distill_updates",
            list(budget.distill_updates),
            f"must have {rounds} entries, one per halving round of planner.num_steps="
            f"{p.num_steps} -> {final_steps}"
            + ("" if final_steps == 1 else " (distillation.final_steps)"),
        )
    check_ablations(cfg)
    check_planner_window(cfg)
    check_augment(cfg)
    check_critic(cfg)
    if cfg.actor.latent == "sample" and p.schedule != "cosine":
        raise ConfigError(
            "actor.latent",
            "sample",
            f"needs planner.schedule=cosine, which ends in pure noise (got {p.schedule})",
        )


def check_critic(cfg: DictConfig) -> None:
    """Checks ``critic`` against Eq. 7's weighting and the online data's labels.

    Eq. 7 on a critic without V (``critic=calql`` or ``so2``, the paper's Cal-QL and SO2
    rows) weighs by Q alone; Cal-QL labels whole episodes online.
    """
    name = cfg.critic.name
    if name != "iql" and cfg.actor.weighting == "advantage":
        raise ConfigError(
            "actor.weighting",
            "advantage",
            f"needs IQL's value network V; critic={name} has none: use actor.weighting=sac "
            "(Q - alpha log pi, the paper's Cal-QL and SO2 rows) or uniform",
        )
    if name == "calql" and cfg.augment.kind != "none":
        raise ConfigError(
            "augment.kind",
            cfg.augment.kind,
            "adds generated transitions without Cal-QL's Monte-Carlo bound; use "
            "augment.kind=none with critic=calql",
        )


def check_ablations(cfg: DictConfig) -> None:
    """The ablation switches' combinations (docs/recipe.md, "DUAL ablations")."""
    if cfg.actor.init == "scratch":
        if cfg.exploration.transition_model == "shared" and cfg.exploration.shift_weight > 0:
            raise ConfigError(
                "exploration.transition_model",
                "shared",
                "with actor.init=scratch the actor is no planner: ŝ_t needs "
                "exploration.transition_model=frozen (the distilled planner), or "
                "exploration.shift_weight=0",
            )
        if cfg.distillation.final_steps != 1:
            raise ConfigError(
                "actor.init",
                "scratch",
                "is the one-step actor without the planner prior; it needs "
                f"distillation.final_steps=1 (got {cfg.distillation.final_steps})",
            )
    if cfg.laplace.uq == "latent":
        if cfg.laplace.num_samples < 2:
            raise ConfigError(
                "laplace.num_samples",
                cfg.laplace.num_samples,
                "must be >= 2 with laplace.uq=latent (the spread over M latents is the "
                "epistemic part; for no UQ use laplace.uq=laplace laplace.num_samples=0)",
            )
        if cfg.planner.schedule != "cosine":
            raise ConfigError(
                "laplace.uq",
                "latent",
                "needs planner.schedule=cosine, which ends in pure noise so that "
                f"τ^N ~ N(0, I) (got {cfg.planner.schedule})",
            )


DUAL = AlgorithmSettings(
    sections={
        "planner": PlannerSettings,
        "distillation": DistillationSettings,
        "actor": ActorSettings,
        "laplace": LaplaceSettings,
        "exploration": ExplorationSettings,
        "online": OnlineSettings,
        "augment": AugmentSettings,
    },
    critics=("iql", "calql", "so2"),
    check=check_dual,
)


@dataclass(frozen=True)
class DualSections:
    """DUAL's config sections, typed: what its learner and builders read.

    What :class:`~torchrl_dual.recipe.algos.dual.DualLearner` and its builders read
    (:meth:`of` a validated config).

    Examples:
        >>> from torchrl_dual.recipe import compose_checked, CONFIG_DIR
        >>> cfg = compose_checked(CONFIG_DIR, ["budget=smoke"])
        >>> sections = DualSections.of(cfg)
        >>> sections.planner.num_steps, sections.distillation.final_steps
        (32, 1)
    """

    planner: PlannerSettings
    distillation: DistillationSettings
    actor: ActorSettings
    laplace: LaplaceSettings
    exploration: ExplorationSettings
    online: OnlineSettings
    augment: AugmentSettings

    @classmethod
    def of(cls, cfg: DictConfig) -> DualSections:
        """The sections of ``cfg`` (which passed ``validate_config``) as their schemas."""
        return cls(**{f.name: as_settings(DUAL.sections[f.name], cfg[f.name]) for f in fields(cls)})
