"""DUAL's config sections (``algo/dual.yaml``), their checks across keys, and its entry.

The entry is in :data:`~torchrl_dual.recipe.ALGORITHMS`; the learner is
:class:`~torchrl_dual.recipe.algos.dual.DualLearner`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.algo_common import AlgorithmSettings, OnlineSettings
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.names import LATENTS, SCHEDULES, UNCERTAINTIES, WEIGHTINGS
from torchrl_dual.recipe.settings.parts import (
    CRITICS,
    AugmentSettings,
    check_augment,
    check_planner_window,
)
from torchrl_dual.recipe.settings.rules import (
    Choice,
    Either,
    Integer,
    PowerOfTwo,
    Real,
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

    horizon: int = key(
        Integer(1),
        "`H`: windows hold `H + 1` state-action rows (the paper uses 8); episodes shorter than "
        "`H + 1` are never sampled",
    )
    num_steps: int = key(
        PowerOfTwo(),
        "`N`, sampling steps of the teacher (the paper's 32); a power of two, since DUAL's "
        "distillation halves it down to `distillation.final_steps` (1). `algo=diffuser` and "
        "`edis` sample with all `N` steps (the paper's Diffuser uses 20, not a power of two)",
    )
    hidden: int = key(Integer(1), "width of the residual-MLP denoiser")
    depth: int = key(Integer(1), "residual blocks of the denoiser")
    schedule: str = key(
        Choice(SCHEDULES),
        "noise schedule; `actor.latent=sample` and `laplace.uq=latent` need `cosine`, which ends "
        "in pure noise",
    )
    lr: float = key(Real(0, low_open=True), "Adam learning rate")
    batch_size: int = key(Integer(1), "windows per update")
    action_condition_prob: float = key(
        Real(0, 1),
        "probability that `a_0` is given with `s_0` during training and distillation; trains the "
        "transition model into the planner",
    )


@dataclass
class DistillationSettings:
    """Progressive distillation ``N -> 1`` (Salimans & Ho 2022)."""

    lr: float = key(
        Real(0, low_open=True),
        "Adam learning rate of every round (cosine-decayed within a round; the student kept is "
        "the EMA of its weights)",
    )
    final_steps: int = key(
        PowerOfTwo(),
        "steps of the distilled actor, where the halving rounds of `planner.num_steps` stop (at "
        "most `planner.num_steps`); `budget.distill_updates` holds the updates of each round, "
        "one entry per round, `log2(planner.num_steps / final_steps)` of them. `1` is DUAL; `8` "
        'is the paper\'s "w/o distillation" ablation (`distillation.final_steps=8 '
        '"budget.distill_updates=[100,100]"`): the rounds stop at 8 steps (32 → 16 → 8) and '
        "the actor is the 8-step planner, `PlannerActor` running the first 7 DDIM steps with the "
        "current weights and reading `τ_{a_0}` out of the last step, which is affine in that "
        "step's final `nn.Linear`, so Eq. 8's Laplace stays exact (the earlier steps are fixed "
        "features, as `DDPMLastStepActor` does for Diff-QL); its mean is the deterministic "
        "8-step planner's `a_0`, and the frozen transition model is the 8-step student too. "
        "Cost: 8 denoiser passes per action for the actor and 8 for `ŝ_t` (no one-step fast "
        "path; `dual_m5_n8` in `benchmarks/speed/latency.py`, ≈ 19× `dual_m5`: 41.6 vs 2.2 ms "
        "on a loaded 2-core machine), and every Eq. 7 update back-propagates through the 8-step "
        "chain (≈ 8× the actor step). Changes the offline stages; "
        "[DUAL ablations](recipe.md#dual-ablations)",
    )


@dataclass
class ActorSettings:
    """Weighted MAP actor (Eq. 7)."""

    weighting: str = key(
        Choice(WEIGHTINGS),
        "per-sample weights of Eq. 7: `advantage` = `min(exp(β·(Q − V)), w_max)`, IQL's weights "
        "(needs IQL's `V`: `critic=iql`); `sac` = Cal-QL-style `α·log π(a) − Q(s, a)` on a "
        "reparameterised draw `a` clamped to the env's action box and scored as a censored "
        "Gaussian ([equations.md deviation 2a]"
        "(equations.md#2a-the-sac-weighting-sees-the-executed-clamped-action)), `α` = "
        "`critic.entropy_coef` on SO2, 0.2 on Cal-QL; `uniform` = behaviour cloning. Default: "
        "the critic's preset `critic.actor_weighting` (`advantage` on `iql`, `sac` on `calql` "
        "and `so2`). The Laplace fit weights samples by the advantage weights for `advantage` "
        "and uniformly otherwise",
    )
    temperature: float = key(
        Real(0),
        "`β` of the advantage weights `exp(β·(Q − V))`; default: the env family's preset "
        "`env.actor_temperature` (CORL's IQL `β`)",
    )
    max_weight: float = key(Real(0, low_open=True), "`w_max`, clip of the advantage weights")
    lr: float = key(
        Real(0, low_open=True),
        "Adam learning rate; fine-tunes the whole one-step planner and `σ̄`",
    )
    init_std: float = key(
        Real(0, low_open=True), "initial `σ̄`, the learnable action std, in action units"
    )
    latent: str = key(
        Choice(LATENTS),
        "latent of the one-step planner: `zero` (deterministic mean: keeps `μ(s)` a "
        "deterministic function of the state in every ablation) or `sample` (needs "
        "`planner.schedule=cosine`); with `laplace.uq=latent` the members draw their latents "
        "whatever it says, and evaluation acts with this mean",
    )
    init: str = key(
        Choice(ACTOR_INITS),
        "what the actor starts from: `distilled` = the distilled planner (DUAL); `scratch` = "
        'the paper\'s "w/o planner" ablation (no planner-prior extraction): the one-step '
        "actor keeps its fresh initialisation (the planner's architecture, a copy of the "
        "untrained teacher's weights, the normalizer fitted on `D_offline`) and is trained by "
        "Eq. 7 only; the planner is still trained and distilled, because the frozen transition "
        "model (`ŝ_t`, Eq. 10) is the distilled student, so `λ` keeps its meaning. `scratch` "
        "needs `distillation.final_steps=1` and, unless `exploration.shift_weight=0`, "
        "`exploration.transition_model=frozen`; costs as DUAL; changes the offline stages "
        "([DUAL ablations](recipe.md#dual-ablations))",
    )


@dataclass
class EnsembleSettings:
    """The Laplace ensemble's keys of Eq. (8-9) that every algorithm acting with it has.

    ``dual``, ``iql_la``, ``diffql_la``: what
    :func:`~torchrl_dual.recipe.parts.networks.make_policy` reads.
    """

    num_samples: int = key(
        Integer(0),
        "`M` sub-policies (the paper's 5, for DUAL, IQL + LA and Diff-QL w LA); `0` = no "
        'epistemic UQ, the paper\'s "w/o epistemic UQ" ablation (`laplace.num_samples=0`): '
        "act with the MAP mean and `σ̄` only, no posterior fitted or drawn (cheaper than DUAL: "
        "no `M` heads, no refits); `M = 1` would still act with one posterior draw, a different "
        "policy. With `laplace.uq=latent`: the number of latents, at least 2",
    )
    prior_precision: Any = key(
        Either(
            (Choice(("evidence",)), Real(0, low_open=True)), "must be 'evidence' or a number > 0"
        ),
        "`λ` of the Gaussian prior: `evidence` = maximise the marginal likelihood (the Laplace "
        "evidence of Thm. 3.3), or a fixed positive number (e.g. "
        "`laplace.prior_precision=1.0 actor.weighting=uniform`)",
    )
    posterior_temperature: Any = key(
        Either((Choice(("data",)), Real(0, low_open=True)), "must be 'data' or a number > 0"),
        "`T`: the posterior covariance is `T·P⁻¹` (`λ` as at `T = 1`; `1.0`: the Laplace of the "
        "summed loss); `data`: the Laplace of Eq. 7's *mean* loss (the paper's literal "
        "expectation), `P = G/(Nσ̄²) + λI` with `N` the fitted samples, about `N` times wider "
        "than the Laplace of the summed loss (`LastLayerLaplace(temperature=...)`). An online "
        "key: runs that differ in it share the offline phase. `data` is the only setting that "
        "reached the reward where the offline data never went "
        "([results](results.md#what-the-tables-cannot-say)), and costs on U-maze, whose data "
        "cover the maze. Not to be confused with `diffql_la`'s `laplace.temperature`, the `β` "
        "of its fit's weights",
    )


@dataclass
class LaplaceSettings(EnsembleSettings):
    """Last-layer Laplace ensemble (Eq. 8-9), DUAL's."""

    uq: str = key(
        Choice(UNCERTAINTIES),
        "where the `M` sub-policies come from: `laplace` = `M` posterior heads (Eq. 8); "
        '`latent` = the paper\'s "Ours w τ^N sampling" (Fig. ablation (c)): `M = '
        "laplace.num_samples` latents `τ^N ~ N(0, I)` through the actor with its current (MAP) "
        "weights, aggregated by Eq. 9 (mean and variance over the `M` actions), then the "
        "shift-aware noise as usual (`LatentEnsembleActor`, "
        "`torchrl_dual/modules/laplace/latent_ensemble_actor.py`); no posterior is fitted, and "
        "evaluation acts with the actor's mean (`actor.latent`). `latent` needs "
        "`laplace.num_samples >= 2` and `planner.schedule=cosine` (so that `τ^N ~ N(0, I)`); "
        "it costs `M` trunk passes per action instead of one (≈ 1.5× `dual_m5`, measured under "
        "load) and no Laplace fits. An online key: shares the offline phase "
        "([DUAL ablations](recipe.md#dual-ablations))",
    )


@dataclass
class ExplorationSettings:
    """Shift-aware exploration (Eq. 10)."""

    shift_weight: float = key(
        Real(0),
        "`λ` of the shift-aware variance `λ·d_t` of Eq. 10 (the paper's 0.5); `0` drops the "
        'term: the paper\'s "w/o shift-aware" ablation (`exploration.shift_weight=0`, costs as '
        "DUAL)",
    )
    shift_floor: Any = key(
        Either((Choice(("offline",)), Real(0)), "must be 'offline' or a number >= 0"),
        "`d_0` in `λ·max(d_t − d_0, 0)`, beyond the paper (`0` is Eq. 10); `offline`: the "
        "frozen transition model's mean `‖ŝ' − s'‖` on D_offline, measured once after the "
        "offline stages (stage `shift_floor`, logged as `exploration/shift_floor`, "
        "checkpointed). The model's own error makes `d_t` positive without any shift (U-maze: "
        "0.27 on the data, 0.31 online unshifted, 0.39-0.47 under the shifts; "
        "`benchmarks/studies/shift_signal.py`); the floor keeps that error from adding noise "
        "everywhere. Online-only: shares the offline phase",
    )
    extra_variance: float = key(
        Real(0),
        "`v_c` added to every action's variance, beyond the paper (`0` is Eq. 10): "
        "`σ² + v_c + λ·max(d_t − d_0, 0)`. With `shift_weight=0` and `v_c` = `λ` times the "
        "typical `d_t` it is Eq. 10's control, the same extra noise independent of the state "
        "(the suite's `dual_constant_noise`: 0.15 = 0.5 × the mean `d_t` 0.30 of DUAL's runs on "
        "Medium). Online-only: shares the offline phase",
    )
    transition_model: str = key(
        Choice(TRANSITION_MODELS),
        "where `ŝ_t` (for `d_t`) comes from: `frozen` = the distilled student's weights, kept "
        "frozen while the actor is fine-tuned (the distilled offline copy); `shared` = the "
        "actor's own fine-tuned planner, Alg. 1's literal `p_θ`. One batched trunk pass either "
        "way ([deviation 5](equations.md#5-one-network-for-the-policy-and-the-transition-model)). "
        "With `actor.init=scratch` and `shift_weight > 0` it must be `frozen`",
    )


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
    name, critic = cfg.critic.name, CRITICS[cfg.critic.name]
    if not critic.has_value and cfg.actor.weighting == "advantage":
        raise ConfigError(
            "actor.weighting",
            "advantage",
            f"needs IQL's value network V; critic={name} has none: use actor.weighting=sac "
            "(Q - alpha log pi, the paper's Cal-QL and SO2 rows) or uniform",
        )
    if critic.monte_carlo_labels and cfg.augment.kind != "none":
        raise ConfigError(
            "augment.kind",
            cfg.augment.kind,
            f"adds generated transitions without the Monte-Carlo bound of critic={name}; use "
            f"augment.kind=none with critic={name}",
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
