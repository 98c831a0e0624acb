"""The metrics logger's schema (``logger.*``): TorchRL's logger backends, with their checks.

:data:`LOGGERS` holds each ``logger.backend`` of ``torchrl.record.loggers.get_logger``: its
keys, the package it needs and whether a run can resume it.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.rules import Choice, Maybe, Text, key

WANDB_MODES = ("offline", "online", "disabled")


@dataclass
class LoggerSettings:
    """``logger/*.yaml``: the keys every backend has."""

    backend: str = key(
        Text(),
        "the TorchRL logger backend (the `LOGGERS` entry, `torchrl.record.loggers.get_logger`'s "
        "type), chosen with `logger=csv` (default), `logger=tensorboard`, `logger=wandb`, or "
        "`logger.backend=mlflow` or `trackio`; every backend gets the same scalars under "
        "`<output_dir>/logs`: `csv` one CSV file per scalar under `logs/<algo>/scalars`, "
        "`tensorboard` event files under `logs/<algo>` (`tensorboard --logdir "
        "<output_dir>/logs`), `wandb` the run's files under `logs/wandb`, with the resolved "
        "config as the W&B run's config. All but `csv` need their package "
        "(`pip install 'torchrl-dual[tensorboard]'`, `'torchrl-dual[wandb]'`, `mlflow`, "
        "`trackio`); `resume=true` needs `csv`, `tensorboard` or `wandb` "
        "([Loggers](recipe.md#loggers))",
    )


@dataclass
class WandbSettings(LoggerSettings):
    """``logger/wandb.yaml``: where the Weights & Biases run goes (``wandb.init``)."""

    project: str = key(Text(), "the W&B project")
    entity: Any = key(Maybe(Text()), "the W&B user or team; `null`: your account's default entity")
    mode: str = key(
        Choice(WANDB_MODES),
        "`offline`: local files only, no account or network needed, uploaded later by "
        "`wandb sync <output_dir>/logs/wandb/offline-run-*`; `online`: logs live (needs "
        "`wandb login`); `disabled`",
    )


@dataclass(frozen=True)
class LoggerBackend:
    """One ``logger.backend``: its config schema, the package it needs and whether it resumes.

    How to install the package, and whether TorchRL can resume the backend from a
    checkpoint.
    """

    settings: type
    package: str | None = None
    install: str | None = None
    resumable: bool = False


LOGGERS: dict[str, LoggerBackend] = {
    "csv": LoggerBackend(LoggerSettings, resumable=True),
    "tensorboard": LoggerBackend(
        LoggerSettings, "tensorboard", "pip install 'torchrl-dual[tensorboard]'", True
    ),
    "wandb": LoggerBackend(WandbSettings, "wandb", "pip install 'torchrl-dual[wandb]'", True),
    "mlflow": LoggerBackend(LoggerSettings, "mlflow", "pip install mlflow"),
    "trackio": LoggerBackend(LoggerSettings, "trackio", "pip install trackio"),
}
"""``torchrl.record.loggers.get_logger``'s backends (TorchRL 0.14.1); ``resumable``: its
``state_dict=`` accepts them."""


def check_logger(cfg: DictConfig) -> None:
    """What ``cfg.logger`` asks of the machine.

    The backend's package, and a backend that resumes when ``resume=true``.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> check_logger(OmegaConf.create({"logger": {"backend": "mlflow"}, "resume": True}))
        Traceback (most recent call last):
        ...
        torchrl_dual.recipe.settings.errors.ConfigError: logger.backend=mlflow: ...
    """
    backend = LOGGERS[cfg.logger.backend]
    if backend.package is not None and importlib.util.find_spec(backend.package) is None:
        raise ConfigError(
            "logger.backend",
            cfg.logger.backend,
            f"needs the {backend.package} package ({backend.install})",
        )
    if cfg.resume and not backend.resumable:
        resumable = [name for name, b in LOGGERS.items() if b.resumable]
        raise ConfigError(
            "logger.backend",
            cfg.logger.backend,
            f"cannot resume (resume=true); use one of {', '.join(resumable)}",
        )
