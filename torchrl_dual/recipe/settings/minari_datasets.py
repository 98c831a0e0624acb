"""The Minari families' data sets: their ids (:data:`FAMILIES`) and the data-on-disk check.

Each Minari ``env.kind`` (``antmaze``, ``locomotion``, ``adroit``) reads published data
sets whose id comes from ``env.task``, ``env.dataset`` and ``env.dataset_version``;
:func:`check_minari_dataset` stops a run before any work when the data set cannot be
read, and names the ``minari download`` command.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError

PROTOCOLS = ("d4rl", "minari")
"""Values of ``env.protocol`` (``torchrl_dual.recipe.kits.d4rl_protocol``)."""


@dataclass(frozen=True)
class MinariFamily:
    """Published Minari data sets of one env kind.

    Args:
        id_format (str): the data set id with ``{task}``, ``{dataset}``, ``{version}``.
        tasks (tuple of str): values of ``env.task`` (empty: the family has one task).
        datasets (tuple of str): known data set names (others are accepted: Minari grows).
    """

    id_format: str
    tasks: tuple[str, ...]
    datasets: tuple[str, ...]

    def dataset_id(self, env: Any) -> str:
        """The Minari id of the ``env`` section's ``task``, ``dataset`` and ``dataset_version``."""
        task = getattr(env, "task", "")
        return self.id_format.format(task=task, dataset=env.dataset, version=env.dataset_version)


FAMILIES: dict[str, MinariFamily] = {
    "antmaze": MinariFamily(
        "D4RL/antmaze/{dataset}-{version}",
        (),
        ("umaze", "umaze-diverse", "medium-play", "medium-diverse", "large-play", "large-diverse"),
    ),
    "locomotion": MinariFamily(
        "mujoco/{task}/{dataset}-{version}",
        ("hopper", "halfcheetah", "walker2d"),
        ("medium", "expert", "simple"),
    ),
    "adroit": MinariFamily(
        "D4RL/{task}/{dataset}-{version}",
        ("pen", "door", "hammer", "relocate"),
        ("cloned", "human", "expert"),
    ),
}
"""``env.kind`` -> :class:`MinariFamily`."""


def check_minari_dataset(cfg: DictConfig) -> None:
    """Stops before any work when the Minari data set cannot be read.

    It stops when minari is missing, ``MINARI_DATASETS_PATH`` is not a directory, the
    data set is not on disk or its ``metadata.json`` does not parse.
    """
    dataset_id = FAMILIES[cfg.env.kind].dataset_id(cfg.env)
    try:
        from minari.storage import get_dataset_path
    except ImportError as err:
        raise ConfigError(
            "env.kind",
            cfg.env.kind,
            "reading Minari data sets needs the minari package: pip install 'torchrl-dual[minari]'",
        ) from err
    try:
        path = get_dataset_path(dataset_id)  # creates the directories: fails on a file
    except OSError as err:
        reason = f"{err.strerror}: {err.filename}"
        root = os.environ.get("MINARI_DATASETS_PATH")
        if root:
            raise ConfigError(
                "MINARI_DATASETS_PATH",
                root,
                f"not a directory Minari can use ({reason}); point it at a directory, or "
                "unset it to use ~/.minari/datasets",
            ) from err
        raise ConfigError(
            None,
            None,
            f"Minari's data sets directory cannot be used ({reason}); set "
            "MINARI_DATASETS_PATH to a directory",
        ) from err
    if not (path / "data").exists():
        raise ConfigError(
            "env.dataset",
            cfg.env.dataset,
            f"the Minari data set {dataset_id} is not on disk (looked in {path}; set "
            f"MINARI_DATASETS_PATH to look elsewhere); download it with: "
            f"minari download {dataset_id}",
        )
    metadata = path / "data" / "metadata.json"  # Minari reads it first
    try:
        if metadata.is_file():
            json.loads(metadata.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ConfigError(
            "env.dataset",
            cfg.env.dataset,
            f"the Minari data set {dataset_id} is damaged: {metadata} cannot be read ({err}); "
            f"download it again with: minari download --force {dataset_id}",
        ) from err
