"""What the recipe needs from one kind of environment: :class:`EnvKit` and the ``env.*``
keys every kit has (:class:`EnvSettings`). The table of kits is
:data:`torchrl_dual.recipe.kits.build.ENV_KITS`."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from omegaconf import DictConfig
from torch import nn
from torchrl.envs import EnvBase

from torchrl_dual.data import OfflineDataset
from torchrl_dual.recipe.settings.rules import Integer, Real, Text, key

Evaluator = Callable[[nn.Module], dict[str, float]]
"""``policy -> {"return": ..., "normalized_score": ..., ...}`` under deterministic actions
(``normalized_score`` is NaN when the data set has no reference returns)."""


@dataclass(frozen=True)
class EnvKit:
    """What the recipe needs from one kind of environment.

    Args:
        settings (type): schema dataclass of the ``env.*`` keys, a subclass of
            :class:`EnvSettings` (see ``rules.key``).
        load_data (callable): ``cfg -> OfflineDataset``, ``D_offline`` (cached or read).
        make_env (callable): ``(cfg, data) -> EnvBase``, the online env (the recipe appends
            :class:`~torchrl_dual.transforms.PreviousTransition` for Eq. 10's ``d_t``);
            ``data`` (``D_offline``, or ``None``: the kit reads it if it needs it) carries
            what the env must agree with (e.g. observation normalization).
        make_evaluator (callable): ``(cfg, data) -> Evaluator``.
        action_projection (callable, optional): maps the sampled action to the executed
            one (stored in the replay buffer), e.g. the one-hot argmax of a discrete env.
        check (callable, optional): ``cfg -> None``, run by ``validate_config`` before
            anything else; raises :class:`~torchrl_dual.recipe.settings.errors.ConfigError` for what
            the machine lacks (e.g. a Minari data set that is not on disk).
    """

    settings: type
    load_data: Callable[[DictConfig], OfflineDataset]
    make_env: Callable[[DictConfig, OfflineDataset | None], EnvBase]
    make_evaluator: Callable[[DictConfig, OfflineDataset], Evaluator]
    action_projection: Callable[[torch.Tensor], torch.Tensor] | None = None
    check: Callable[[DictConfig], None] | None = None


@dataclass
class EnvSettings:
    """The ``env.*`` keys every kit has; a kit's schema adds its own."""

    name: str = key(Text(), "used in output_dir and the plot title")
    kind: str = key(Text(), "the ENV_KITS entry")
    max_episode_steps: int = key(Integer(1), "time limit of an episode")
    critic_expectile: float = key(
        Real(0, 1, low_open=True, high_open=True),
        "the family's preset of critic.expectile (CORL's IQL tau)",
    )
    actor_temperature: float = key(
        Real(0, low_open=True), "the family's preset of the actors' temperature (CORL's beta)"
    )
