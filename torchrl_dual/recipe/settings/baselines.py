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

    hidden: int = key(Integer(1), "MLP width of the actor")
    depth: int = key(Integer(1), "hidden layers of the actor")
    lr: float = key(Real(0, low_open=True), "Adam learning rate of the actor (Cal-QL: and log α)")


@dataclass
class IQLActorSettings(MLPActorSettings):
    """``algo/iql.yaml``'s ``actor``: the Gaussian MLP actor and its AWR loss."""

    temperature: float = key(Real(0), "β of exp(β (Q - V)), clipped at 100 by IQLLoss")
    distribution: str = key(
        Choice(ACTOR_DISTRIBUTIONS),
        "gaussian: N(tanh mean on the box, state-independent σ) as CORL and d3rlpy; "
        "tanh_normal: TorchRL's TanhNormal(loc(s), scale(s))",
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
        "σ̄: the IQL actor's RMS std at each fit, or a fixed value",
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

    num_steps: int = key(Integer(1), "N: DDPM denoising steps")
    hidden: int = key(Integer(1), "width of the score network")
    depth: int = key(Integer(1), "hidden layers of the score network")
    activation: str = key(Choice(DIFFQL_ACTIVATIONS), "activation of the score network")
    lr: float = key(Real(0, low_open=True), "Adam learning rate")
    eta: float = key(Real(0), "η: weight of the normalised Q-term")
    max_grad_norm: float = key(Real(0, low_open=True), "clip of the actor's gradient norm")


@dataclass
class DiffQLLaplaceSettings(EnsembleSettings):
    """``algo/diffql_la.yaml``'s ``laplace``: Eq. (8-9) on the last DDPM step.

    DUAL's keys of Eq. 8-9, with DUAL's rules, and the weights of the fit.
    """

    temperature: float = key(Real(0), "β of the Laplace fit's weights exp(β (Q - V))")
    max_weight: float = key(Real(0, low_open=True), "clip of those weights")


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

    noise_scale: float = key(Real(0, low_open=True), "noise std per unit of α")
    init_alpha: float = key(Real(0, low_open=True), "α when the online phase starts")
    target_entropy: Any = key(Maybe(Real()), "H̄ in nats; null: DACER's −0.9 · dim(A)")
    alpha_lr: float = key(Real(0, low_open=True), "Adam learning rate of log α")
    entropy_every: int = key(Integer(1), "online updates between entropy estimates")
    num_states: int = key(Integer(1), "states of the update's batch Ĥ is averaged over")
    num_samples: int = key(Integer(1), "K: exploration actions sampled per state")
    num_components: int = key(Integer(1), "C: components of the Gaussian mixture")


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

    sampler: str = key(Choice(SAMPLERS), "sampler of the exploration plans (random latent)")


@dataclass
class DiffuserOnlineSettings(OnlineSettings):
    """The Diffuser's online phase: it draws its own window batches, so a fixed share."""

    offline_fraction: float = key(
        Real(0, 1, low_open=True, high_open=True), "share of each window batch from D_offline"
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
