"""The baselines' config sections (``algo/<name>.yaml``), their checks and their entries.

The entries are in :data:`~torchrl_dual.recipe.ALGORITHMS`; each learner is in its own
module of :mod:`torchrl_dual.recipe.algos`.

Sections another algorithm defines are reused, not copied: ``edis`` and ``diffuser``
read DUAL's ``planner``, ``iql_la`` DUAL's ``laplace`` keys, ``dacer`` Diff-QL's
``actor``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.algo_common import (
    AlgorithmSettings,
    NoShiftExplorationSettings,
    OnlineSettings,
    check_no_shift_weight,
    check_nothing,
)
from torchrl_dual.recipe.settings.dual import EnsembleSettings, PlannerSettings
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.names import SAMPLERS
from torchrl_dual.recipe.settings.parts import AugmentSettings, check_augment, check_planner_window
from torchrl_dual.recipe.settings.rules import (
    Choice,
    Either,
    Integer,
    Maybe,
    Real,
    key,
)

# ----------------------------------------------------------------------------- IQL
ACTOR_DISTRIBUTIONS = ("gaussian", "tanh_normal")
"""``actor.distribution`` of the AWR baselines: ``gaussian`` (CORL's and d3rlpy's IQL actor,
the default) or ``tanh_normal`` (TorchRL's ``TanhNormal`` with a state-dependent scale)."""


@dataclass
class MLPActorSettings:
    """``actor`` of the MLP-actor baselines: its width, depth and learning rate.

    ``algo/calql.yaml`` and ``algo/so2.yaml``: the tanh-Gaussian actor of a SAC actor
    loss; Cal-QL's ``lr`` is also that of ``log α``.
    """

    hidden: int = key(
        Integer(1),
        "MLP width of the actor: the Gaussian AWR actor of `iql`, `iql_la` and `edis`, the "
        "tanh-Gaussian SAC actor of `calql` and `so2` (CORL's IQL, Cal-QL and SO2: 256, the "
        "default budget's `budget.network_width`)",
    )
    depth: int = key(
        Integer(1),
        "hidden layers of the actor (CORL's IQL: 2). `algo=calql` reads the reference preset "
        "`${reference:actor.depth,2}` (`settings/references.py`): 3 on Adroit, as CORL's "
        "Cal-QL (its `TanhGaussianPolicy` has 3 hidden layers), 2 elsewhere; a value on the "
        "command line replaces it",
    )
    lr: float = key(
        Real(0, low_open=True),
        "Adam learning rate of the actor, no cosine decay here (CORL's IQL: 3e-4; SO2: 3e-4, "
        "its `α` fixed at `critic.entropy_coef`). `algo=calql`: also that of `log α` of SAC's "
        "automatic entropy tuning (Cal-QL: 1e-4)",
    )


@dataclass
class IQLActorSettings(MLPActorSettings):
    """``algo/iql.yaml``'s ``actor``: the Gaussian MLP actor and its AWR loss."""

    temperature: float = key(
        Real(0),
        "`β` of the advantage weights `exp(β·(Q − V))`, clipped at 100 by `IQLLoss`; by "
        "default the env family's preset `env.actor_temperature` (CORL's IQL β: 10 on "
        "AntMaze, 3 for the other mazes, locomotion and Adroit). With `algo=iql_la` the same "
        "weights also weight the Laplace fit (Eq. 8)",
    )
    distribution: str = key(
        Choice(ACTOR_DISTRIBUTIONS),
        "`gaussian`: CORL's and d3rlpy's IQL actor, `N(c + r·tanh(f(s)), diag σ²)` on the "
        "env's box with one learned `σ` per action dimension (TensorDict's "
        "`AddStateIndependentNormalScale`, initial 1), draws projected onto the box "
        "(`safe=True`), evaluated at the mean; `tanh_normal`: TorchRL's "
        "`TanhNormal(loc(s), scale(s))` with a state-dependent scale, evaluated at "
        "`tanh(loc(s))`. With `algo=iql_la` the Laplace fit is a Gauss-Newton fit through the "
        "tanh for `gaussian` and exact in the pre-tanh space for `tanh_normal`. Why "
        "`gaussian` is the default: [Algorithms, critics and env kits]"
        "(recipe.md#algorithms-critics-and-env-kits)",
    )


IQL = AlgorithmSettings(
    sections={"actor": IQLActorSettings, "online": OnlineSettings},
    critics=("iql",),
    check=check_nothing,
)


@dataclass
class IQLLALaplaceSettings(EnsembleSettings):
    """``algo/iql_la.yaml``'s ``laplace``: DUAL's Eq. (8-9) keys for a plain actor, and ``σ̄``.

    ``M``, the prior and ``T``, with DUAL's rules, and where ``σ̄`` comes from.
    """

    noise_std: Any = key(
        Either(
            (Choice(("iql",)), Real(0, 2, low_open=True)), "must be 'iql' or a number in (0, 2]"
        ),
        "`σ̄`, the aleatoric std of Eq. 9 and of the noise (λ = 0): `iql`: the IQL actor's "
        "own std, root mean square over the fit data, set at each fit with the posterior "
        "(after the offline updates and every `budget.laplace_refit_every` updates), in "
        "action units for `actor.distribution=gaussian` and pre-tanh for `tanh_normal`, "
        "clamped to `[1e-3, 2]`; a number fixes `σ̄` (e.g. `laplace.noise_std=0.3`, DUAL's "
        "`actor.init_std`). An online key: runs that differ in it share the offline phase",
    )


IQL_LA = AlgorithmSettings(
    sections={
        "actor": IQLActorSettings,
        "laplace": IQLLALaplaceSettings,
        "exploration": NoShiftExplorationSettings,
        "online": OnlineSettings,
    },
    critics=("iql",),
    check=check_no_shift_weight,
)


# ----------------------------------------------------------------------------- Diff-QL
DIFFQL_ACTIVATIONS = ("silu", "mish")
"""``actor.activation`` (the keys of :data:`~torchrl_dual.recipe.algos.diffql.ACTIVATIONS`):
``silu`` (TorchRL's ``DiffusionActor`` default) or ``mish`` (Wang et al.'s; on one CPU
thread its forward and backward cost 4x SiLU's)."""


@dataclass
class DiffQLActorSettings:
    """``algo/diffql*.yaml``'s ``actor``: the DDPM actor and its loss."""

    num_steps: int = key(
        Integer(1),
        "`N`: DDPM denoising steps of TorchRL's `DiffusionActor` (Wang et al.'s "
        "variance-preserving schedule) in `diffql`, `diffql_la` and `dacer` (Wang et al. "
        "2023: 5)",
    )
    hidden: int = key(
        Integer(1),
        "width of the MLP score network (Wang et al. 2023: 256, the default budget's "
        "`budget.network_width`)",
    )
    depth: int = key(Integer(1), "hidden layers of the score network (Wang et al. 2023: 3)")
    activation: str = key(
        Choice(DIFFQL_ACTIVATIONS),
        "activation of the score network: `silu`, TorchRL `DiffusionActor`'s; `mish`, Wang "
        "et al.'s, whose forward and backward cost 4x SiLU's on one CPU thread",
    )
    lr: float = key(
        Real(0, low_open=True), "Adam learning rate of the actor (Wang et al. 2023: 3e-4)"
    )
    eta: float = key(
        Real(0),
        "`η`: weight of the normalised Q-term of `DiffQLActorLoss`, "
        "`L_bc − η · mean Q(s, a_π) / mean abs(Q(s, a_π))` with `a_π` sampled through the "
        "whole chain and `Q = min(Q_1, Q_2)` detached (1.0 for the mazes)",
    )
    max_grad_norm: float = key(
        Real(0, low_open=True),
        "clip of the actor's gradient norm (Wang et al. clip it per task)",
    )


@dataclass
class DiffQLLaplaceSettings(EnsembleSettings):
    """``algo/diffql_la.yaml``'s ``laplace``: Eq. (8-9) on the last DDPM step.

    DUAL's keys of Eq. 8-9, with DUAL's rules, and the weights of the fit.
    """

    temperature: float = key(
        Real(0),
        "`β` of the weights `exp(β·(Q − V))` of the Laplace fit, which weight both `σ̄` (the "
        "weighted root mean square of the data actions around the zero-latent chain, "
        "Eq. 7's maximiser) and Eq. 8's posterior, as DUAL's `actor.temperature`; by default "
        "the env family's preset `env.actor_temperature`. Not `laplace.posterior_temperature`"
        " (`T`). An online key: runs that differ in it share the offline phase",
    )
    max_weight: float = key(
        Real(0, low_open=True),
        "`w_max`, clip of the weights `exp(β·(Q − V))` of `σ̄` and Eq. 8. An online key: runs "
        "that differ in it share the offline phase",
    )


DIFFQL = AlgorithmSettings(
    sections={"actor": DiffQLActorSettings, "online": OnlineSettings},
    critics=("iql",),
    check=check_nothing,
)


DIFFQL_LA = AlgorithmSettings(
    sections={
        "actor": DiffQLActorSettings,
        "laplace": DiffQLLaplaceSettings,
        "exploration": NoShiftExplorationSettings,
        "online": OnlineSettings,
    },
    critics=("iql",),
    check=check_no_shift_weight,
)


# ----------------------------------------------------------------------------- DACER
@dataclass
class DACERSettings:
    """``algo/dacer.yaml``'s ``dacer``: the entropy regulator of the online phase."""

    noise_scale: float = key(
        Real(0, low_open=True),
        "noise std per unit of `α`: acting is `clamp(a_DDPM + noise_scale · α · ε)` (DACER: "
        "0.15 on Humanoid and HalfCheetah, 0.1 otherwise). An online key, as every `dacer.*` "
        "key: runs that differ in it share the offline phase",
    )
    init_alpha: float = key(
        Real(0, low_open=True),
        "`α` when the online phase starts; not trained offline (DACER: 3). An online key",
    )
    target_entropy: Any = key(
        Maybe(Real()),
        "`H̄` in nats, the target of `L(log α) = −log α · (H̄ − Ĥ)`, which raises `α` while "
        "`Ĥ < H̄`; `null`: DACER's `−0.9 · dim(A)` (−1.8 on PointMaze). An online key",
    )
    alpha_lr: float = key(
        Real(0, low_open=True), "Adam learning rate of `log α` (DACER: 3e-2). An online key"
    )
    entropy_every: int = key(
        Integer(1),
        "online updates between entropy estimates `Ĥ`, each followed by one Adam step on "
        "`log α` (DACER: 10 000 of ~1M updates; 50 gives the default budget's 4000 online "
        "updates 80 steps). One estimate costs about 0.5 CPU-s at the default sizes (≈ 40 "
        "CPU-s a run). An online key",
    )
    num_states: int = key(
        Integer(1),
        "states of the update's batch that `Ĥ` is averaged over (DACER: the whole batch); at "
        "most `online.batch_size`. An online key",
    )
    num_samples: int = key(
        Integer(1),
        "`K`: exploration actions sampled per state for the mixture fit (DACER: 200); at least "
        "`dacer.num_components`, one sampled action per component. An online key",
    )
    num_components: int = key(
        Integer(1),
        "`C`: components of the full-covariance Gaussian mixture fitted by EM to each "
        "state's sampled actions, whose entropy is `Ĥ`'s estimate (`sampled_entropy`: an "
        "upper bound of a mixture's entropy, exact for non-overlapping components) (DACER: "
        "3). An online key",
    )


def check_dacer(cfg: DictConfig) -> None:
    """Checks ``dacer.num_samples`` and ``dacer.num_states`` against their bounds.

    ``dacer.num_samples >= dacer.num_components`` (EM needs a sample per component) and
    ``dacer.num_states <= online.batch_size`` (the states come from the update's batch).
    """
    d = cfg.dacer
    if d.num_samples < d.num_components:
        raise ConfigError(
            "dacer.num_samples",
            d.num_samples,
            f"must be >= dacer.num_components={d.num_components}: the Gaussian mixture "
            "needs at least one sampled action per component",
        )
    if d.num_states > cfg.online.batch_size:
        raise ConfigError(
            "dacer.num_states",
            d.num_states,
            f"must be <= online.batch_size={cfg.online.batch_size}: the entropy is "
            "estimated on states of the update's batch",
        )


DACER = AlgorithmSettings(
    sections={"actor": DiffQLActorSettings, "dacer": DACERSettings, "online": OnlineSettings},
    critics=("iql",),
    check=check_dacer,
)


# ----------------------------------------------------------------------------- Diffuser
@dataclass
class DiffuserSettings:
    """How the ``N``-step plan explores online."""

    sampler: str = key(
        Choice(SAMPLERS),
        "sampler of the exploration plans, drawn from a random latent with all "
        "`planner.num_steps` steps: `ddim`: the latent is the plan's only randomness; `ddpm`: "
        "fresh noise at every step. Evaluation acts with the deterministic DDIM plan of the "
        "zero latent whatever it says. An online key: runs that differ in it share the "
        "offline phase",
    )


@dataclass
class DiffuserOnlineSettings(OnlineSettings):
    """The Diffuser's online phase: it draws its own window batches, so a fixed share."""

    offline_fraction: float = key(
        Real(0, 1, low_open=True, high_open=True),
        "share of each window batch drawn from `D_offline`, the rest from the online windows; "
        "no `joint`, since the Diffuser draws its own window batches. Each online update is "
        "one `L_VLB` step on `planner.batch_size` windows (`online.utd_ratio` counts them), "
        "so `online.batch_size` is not used",
    )


DIFFUSER = AlgorithmSettings(
    sections={
        "planner": PlannerSettings,
        "diffuser": DiffuserSettings,
        "online": DiffuserOnlineSettings,
    },
    critics=("iql",),  # the critic section is not read: the Diffuser has no critic
    check=check_planner_window,
)


# ----------------------------------------------------------------------------- EDIS
def check_edis(cfg: DictConfig) -> None:
    """The window fits an episode; EDIS is IQL plus the augmentation, so it is on."""
    check_planner_window(cfg)
    if cfg.augment.kind != "planner":
        raise ConfigError(
            "augment.kind",
            cfg.augment.kind,
            "must be planner for algo=edis (EDIS is IQL plus planner augmentation; IQL "
            "alone is algo=iql)",
        )
    check_augment(cfg)


EDIS = AlgorithmSettings(
    sections={
        "planner": PlannerSettings,
        "actor": IQLActorSettings,
        "online": OnlineSettings,
        "augment": AugmentSettings,
    },
    critics=("iql",),
    check=check_edis,
)


# ----------------------------------------------------------------------------- Cal-QL
CALQL = AlgorithmSettings(
    sections={"actor": MLPActorSettings, "online": OnlineSettings},
    critics=("calql",),
    check=check_nothing,
)


# ----------------------------------------------------------------------------- SO2
SO2 = AlgorithmSettings(
    sections={"actor": MLPActorSettings, "online": OnlineSettings},
    critics=("so2",),
    check=check_nothing,
)
