"""DUAL's config sections (``algo/dual.yaml``), their checks across keys, and its
:data:`~torchrl_dual.recipe.ALGORITHMS` entry."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.diffusion import SCHEDULES
from torchrl_dual.diffusion.model import LATENTS
from torchrl_dual.objectives.weighted_map_actor import WEIGHTINGS
from torchrl_dual.recipe.algorithm import Algorithm, OnlineSettings
from torchrl_dual.recipe.dual import DualLearner
from torchrl_dual.recipe.errors import ConfigError
from torchrl_dual.recipe.networks import TRANSITION_MODELS
from torchrl_dual.recipe.rules import Choice, Either, Integer, PowerOfTwo, Real, key


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


@dataclass
class ActorSettings:
    """Weighted MAP actor (Eq. 7)."""

    weighting: str = key(Choice(WEIGHTINGS), "per-sample weights of Eq. 7")
    temperature: float = key(Real(0), "β of exp(β (Q - V))")
    max_weight: float = key(Real(0, low_open=True), "clip of the advantage weights")
    lr: float = key(Real(0, low_open=True), "Adam learning rate")
    init_std: float = key(Real(0, low_open=True), "initial σ̄")
    latent: str = key(Choice(LATENTS), "one-step planner latent")


@dataclass
class LaplaceSettings:
    """Last-layer Laplace ensemble (Eq. 8-9)."""

    num_samples: int = key(Integer(0), "M sub-policies; 0 = no epistemic UQ (MAP mean, σ̄)")
    prior_precision: Any = key(
        Either(
            (Choice(("evidence",)), Real(0, low_open=True)), "must be 'evidence' or a number > 0"
        ),
        "λ of the Gaussian prior",
    )


@dataclass
class ExplorationSettings:
    """Shift-aware exploration (Eq. 10)."""

    shift_weight: float = key(Real(0), "λ of the shift-aware variance")
    transition_model: str = key(Choice(TRANSITION_MODELS), "where ŝ_t comes from")


def check_dual(cfg: DictConfig) -> None:
    """DUAL's checks across keys, each naming the key at fault and what would fit."""
    p, budget = cfg.planner, cfg.budget
    rounds = int(math.log2(p.num_steps))
    if len(budget.distill_updates) != rounds:
        raise ConfigError(
            "budget.distill_updates",
            list(budget.distill_updates),
            f"must have {rounds} entries, one per halving round of planner.num_steps="
            f"{p.num_steps} -> 1",
        )
    if p.horizon >= cfg.env.max_episode_steps:
        raise ConfigError(
            "planner.horizon",
            p.horizon,
            f"must be < env.max_episode_steps={cfg.env.max_episode_steps} (a window holds "
            "horizon + 1 steps of one episode)",
        )
    if cfg.actor.latent == "sample" and p.schedule != "cosine":
        raise ConfigError(
            "actor.latent",
            "sample",
            f"needs planner.schedule=cosine, which ends in pure noise (got {p.schedule})",
        )


DUAL = Algorithm(
    sections={
        "planner": PlannerSettings,
        "distillation": DistillationSettings,
        "actor": ActorSettings,
        "laplace": LaplaceSettings,
        "exploration": ExplorationSettings,
        "online": OnlineSettings,
    },
    critics=("iql",),
    check=check_dual,
    learner=DualLearner,
)
