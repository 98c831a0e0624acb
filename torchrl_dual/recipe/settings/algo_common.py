"""An entry of the recipe's algorithm table, and the settings several algorithms share.

An :class:`Algorithm` pairs its :class:`AlgorithmSettings` (the config sections it reads
with their schemas, the critics it works with, the checks across its keys) with the
:class:`~torchrl_dual.recipe.o2o.learner.Learner` that runs it (a
:class:`~torchrl_dual.recipe.settings.lazy.Ref`). DUAL's settings are in
:mod:`~torchrl_dual.recipe.settings.dual`, the baselines' in
:mod:`~torchrl_dual.recipe.settings.baselines`;
:data:`~torchrl_dual.recipe.settings.algos.ALGORITHMS` pairs them with their learners by
``algo`` name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.rules import Choice, Either, Integer, Real, key


@dataclass(frozen=True)
class AlgorithmSettings:
    """What :func:`~torchrl_dual.recipe.validate_config` checks of one algorithm.

    Args:
        sections (dict): top-level config section -> schema dataclass of its keys.
        critics (tuple of str): the ``critic`` options it supports.
        check (callable): ``cfg -> None``, raises ``ConfigError`` on an impossible
            combination of keys (run after every key passed its own rule).
    """

    sections: dict[str, type]
    critics: tuple[str, ...]
    check: Callable[[DictConfig], None]


@dataclass(frozen=True)
class Algorithm:
    """One entry of :data:`~torchrl_dual.recipe.settings.algos.ALGORITHMS`.

    It holds the algorithm's settings and the learner
    :func:`~torchrl_dual.recipe.run_o2o` runs.

    Args:
        settings (AlgorithmSettings): its config sections, critics and checks.
        learner (callable): ``O2ORun -> Learner``, usually a
            :class:`~torchrl_dual.recipe.settings.lazy.Ref` to the learner
            class (imported when a run starts, so the table stays torch-free).
        no_cuda_graph (str, optional): why its update cannot be captured as a CUDA graph
            (``compile.cudagraphs=true`` is then refused with this reason); ``None``: its
            update is graph-safe (``tests/recipe/test_graph_safe_updates.py``).

    Examples:
        >>> from torchrl_dual.recipe import ALGORITHMS
        >>> entry = ALGORITHMS["dual"]
        >>> entry.learner  # imported when a run starts: the table stays torch-free
        Ref('torchrl_dual.recipe.algos.dual:DualLearner')
        >>> entry.learner.resolve().__name__, entry.no_cuda_graph
        ('DualLearner', None)
    """

    settings: AlgorithmSettings
    learner: Callable[..., Any]
    no_cuda_graph: str | None = None


@dataclass
class OnlineSettings:
    """Algorithm 1, online phase (lines 10-18)."""

    offline_fraction: Any = key(
        Either(
            (Real(0, 1, low_open=True, high_open=True), Choice(("joint",))),
            "must be a number in (0, 1) or 'joint'",
        ),
        "share of each update batch drawn from the offline data (TorchRL's "
        "`OfflineToOnlineReplayBuffer` needs both parts; Cal-QL's is 0.5), or `joint`: "
        "`D_offline` and `D_online` as one buffer, every transition equally likely, so the "
        "offline share falls as `D_online` grows (CORL's fine-tuning replay; not "
        "`algo=diffuser`, which draws its own windows). Read by `replay=mixed` only "
        "(`replay=balanced` ignores it). `budget=paper` gives `algo=iql` and `dual` `joint`, "
        "CORL's (`torchrl_dual.recipe.settings.references.BUDGET_SETTINGS`; a value on the "
        "command line wins); the other budgets and algorithms keep 0.5",
    )
    utd_ratio: float = key(
        Real(0),
        "gradient updates per collected frame (fractions carry over between batches). "
        "`budget=paper` gives `algo=iql` and `dual` CORL's 1, one update per environment step "
        "(`settings/references.py`); the other budgets are sized for 0.5. With `critic=so2` each "
        "update is `critic.online_steps_per_update` critic steps, each on its own batch, and one "
        "actor step (`algo=so2`: 1, SO2's 1 × 10); `algo=diffuser`: `L_VLB` steps on windows",
    )
    batch_size: int = key(
        Integer(1),
        "transitions per actor-critic update, offline and online (`algo=diffuser` does not read "
        "it: its planner learns from windows of `planner.batch_size`)",
    )


def check_nothing(cfg: DictConfig) -> None:
    """No checks across keys."""


@dataclass
class NoShiftExplorationSettings:
    """``exploration`` of a baseline without a transition model: Eq. (10) with ``λ = 0``.

    ``iql_la``, ``diffql_la``.
    """

    shift_weight: float = key(
        Real(0),
        "`λ` of Eq. 10; must be 0: the actor has no transition model for `ŝ_t` (IQL's actor, "
        "Diff-QL); shift-aware exploration is DUAL's",
    )


def check_no_shift_weight(cfg: DictConfig) -> None:
    """``exploration.shift_weight`` must be 0: the actor predicts no next state ``ŝ_t``."""
    if cfg.exploration.shift_weight != 0:
        raise ConfigError(
            "exploration.shift_weight",
            cfg.exploration.shift_weight,
            f"must be 0 for {cfg.algo}: its actor has no transition model for Eq. 10's ŝ_t; "
            "shift-aware exploration is DUAL's (algo=dual)",
        )
