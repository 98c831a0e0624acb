"""The table of environment kits, one entry per ``env.kind``, and their ``env.*`` schema.

A kit builds the data and the envs of Algorithm 1 line 1.

An :class:`EnvKit` holds everything the recipe needs from one kind of environment: the
schema of its ``env.*`` keys, the offline data set ``D_offline``, the online env, the
evaluator returning D4RL-normalized scores, and the projection of the policy's action
onto what the env executes. The builders are :class:`~torchrl_dual.recipe.settings.lazy.Ref`
s to :mod:`torchrl_dual.recipe.kits` (PointMaze and Frozen-Lake in ``kits.build``, the
Minari families in ``kits.minari_families``), imported when a run starts. Adding an
environment is adding one entry to :data:`ENV_KITS`, its builders and one
``torchrl_dual/recipe/config/env/<name>.yaml`` that sets ``kind``; nothing else in the
recipe branches on the env.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.lazy import Ref
from torchrl_dual.recipe.settings.names import FROZENLAKE_MAPS, POINTMAZE_MAZES, SHIFTS_BY_KIND
from torchrl_dual.recipe.settings.rules import (
    CellList,
    Choice,
    Either,
    Flag,
    Integer,
    IntegerList,
    Maybe,
    Real,
    RealList,
    Text,
    key,
)


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
        check (callable, optional): ``cfg -> None``, run by ``validate_config`` after
            the key checks; raises :class:`~torchrl_dual.recipe.settings.errors.ConfigError` for what
            the machine lacks (e.g. a Minari data set that is not on disk).

    Examples:
        >>> kit = ENV_KITS["frozenlake"]
        >>> kit.settings.__name__, kit.action_projection  # Frozen-Lake executes a one-hot action
        ('FrozenLakeSettings', Ref('torchrl_dual.recipe.kits.build:one_hot_argmax'))
        >>> sorted(ENV_KITS)
        ['adroit', 'antmaze', 'frozenlake', 'locomotion', 'pointmaze']
    """

    settings: type
    load_data: Callable[..., Any]
    make_env: Callable[..., Any]
    make_evaluator: Callable[..., Any]
    action_projection: Callable[..., Any] | None = None
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


# ----------------------------------------------------------------------------- PointMaze
@dataclass
class PointMazeSettings(EnvSettings):
    """``env/pointmaze_*.yaml``: Gymnasium-Robotics PointMaze, maze2d-style local data.

    ``data_avoid_cells`` shapes the offline data only; ``start_avoid_cells`` the online
    env's and the evaluator's starts only (each collector worker's env too), so that an
    exploration task (the goal in cells the data never enter) can keep its episodes from
    starting inside them: ``env.start_avoid_cells=${env.data_avoid_cells}``. Named as its
    data twin, a list of cells left out (Gymnasium-Robotics' reset cells, ``"r"`` in its
    ``maze_map``, are their complement: :func:`~torchrl_dual.envs.start_cells`). It changes
    no offline stage (an online key: runs that differ in it share the offline phase).
    """

    maze: str = key(Choice(POINTMAZE_MAZES), "layout")
    shift: str = key(Choice(SHIFTS_BY_KIND["pointmaze"]), "online-only dynamics shift")
    shift_angle: float = key(Real(-180, 180), "degrees of shift=rotation")
    shift_scale: Any = key(
        Maybe(Either((Real(0, 1000, low_open=True),), "must be a number in (0, 1000]")),
        "factor of shift=damping / mass (null: the shift's default)",
    )
    goal_cell: Any = key(
        Maybe(IntegerList(0)), "fixed goal cell [row, col] (null: a random open cell per episode)"
    )
    data_avoid_cells: Any = key(
        Maybe(CellList()), "open cells the offline data never enter (null: none)"
    )
    start_avoid_cells: Any = key(
        Maybe(CellList()),
        "open cells where no online or evaluation episode starts (null: every open cell but "
        "the goal's, as Gymnasium-Robotics)",
    )
    reward_scale: float = key(
        Real(0, low_open=True), "r' = reward_scale * r + reward_shift (data and online env)"
    )
    reward_shift: float = key(Real(), "added after the scale")


# ----------------------------------------------------------------------------- Frozen-Lake
@dataclass
class FrozenLakeSettings(EnvSettings):
    """``env/frozenlake.yaml``: slippery Frozen-Lake with the paper's slip shift."""

    map_name: str = key(Choice(FROZENLAKE_MAPS), "map")
    offline_success_rate: float = key(Real(0, 1, low_open=True), "intended-move probability")
    online_success_rate: float = key(Real(0, 1, low_open=True), "intended-move probability")
    epsilon: float = key(Real(0, 1), "random-action probability of the behaviour policy")
    shift: str = key(Choice(SHIFTS_BY_KIND["frozenlake"]), "online-only dynamics shift")


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

    def dataset_id(self, env: DictConfig) -> str:
        """The Minari id of ``env.task`` / ``env.dataset`` / ``env.dataset_version``."""
        task = env.get("task", "")
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


@dataclass
class MinariSettings(EnvSettings):
    """``env/antmaze.yaml``, ``env/hopper.yaml``, ...: a Minari data set and its env."""

    max_episode_steps: Any = key(
        Maybe(Integer(1)), "time limit; null: the data set's env spec (AntMaze 700/1000)"
    )
    dataset: str = key(Text(), "data set name, e.g. umaze, medium, cloned")
    dataset_version: str = key(Text(), "Minari version suffix, e.g. v1")
    protocol: str = key(
        Choice(PROTOCOLS), "d4rl: D4RL's task, horizon and references; minari: the data set's"
    )
    reward_scale: Any = key(
        Maybe(
            Either(
                (Real(0, low_open=True), Choice(("returns",))), "must be a number > 0 or 'returns'"
            )
        ),
        "r' = reward_scale * r + reward_shift; returns: T / (max - min episode return); "
        "null: the critic's reference preset (REWARD_TRANSFORMS)",
    )
    reward_shift: Any = key(
        Maybe(Real()), "added after the scale; null: the critic's reference preset"
    )
    normalize_observations: bool = key(Flag(), "states -> (s - mean) / (std + 1e-3) of the data")
    reference_returns: Any = key(
        Maybe(RealList(2)), "[random, expert] returns instead of the data set's references"
    )
    shift_scale: Any = key(
        Maybe(Real(0, low_open=True)), "factor of the shift (null: the shift's default)"
    )


@dataclass
class AntMazeSettings(MinariSettings):
    """``env/antmaze.yaml``: Minari ``D4RL/antmaze/<dataset>-<version>``."""

    shift: str = key(Choice(SHIFTS_BY_KIND["antmaze"]), "online-only dynamics shift")
    goal_noise: bool = key(
        Flag(), "protocol=d4rl: redraw the goal in D4RL's 1.5 x 1.5 square at each reset"
    )
    horizon_seconds: Any = key(
        Maybe(
            Either((Real(0, low_open=True), Choice(("d4rl",))), "must be a number > 0 or 'd4rl'")
        ),
        "episode length in simulated seconds, at the env's 0.05 s step (d4rl: D4RL's "
        "700 / 1000 steps of 0.1 s); null: the protocol's step count",
    )


@dataclass
class LocomotionSettings(MinariSettings):
    """``env/hopper.yaml``, ``halfcheetah.yaml``, ``walker2d.yaml``: MuJoCo locomotion.

    Minari ``mujoco/<task>/<dataset>-<version>`` and the ODRL shifts.
    """

    task: str = key(Choice(FAMILIES["locomotion"].tasks), "the robot")
    shift: str = key(Choice(SHIFTS_BY_KIND["locomotion"]), "online-only dynamics shift (ODRL)")


@dataclass
class AdroitSettings(MinariSettings):
    """``env/adroit.yaml``: Minari ``D4RL/<task>/<dataset>-<version>``."""

    task: str = key(Choice(FAMILIES["adroit"].tasks), "the Adroit hand task")
    shift: str = key(Choice(SHIFTS_BY_KIND["adroit"]), "online-only dynamics shift")


MINARI_SETTINGS: dict[str, type] = {
    "antmaze": AntMazeSettings,
    "locomotion": LocomotionSettings,
    "adroit": AdroitSettings,
}


# ----------------------------------------------------------------------------- checks
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


# ----------------------------------------------------------------------------- the table
_BUILD = "torchrl_dual.recipe.kits.build"
_MINARI = "torchrl_dual.recipe.kits.minari_families"

ENV_KITS: dict[str, EnvKit] = {
    "pointmaze": EnvKit(
        PointMazeSettings,
        Ref(f"{_BUILD}:pointmaze_data"),
        Ref(f"{_BUILD}:pointmaze_env"),
        Ref(f"{_BUILD}:pointmaze_evaluator"),
        check=Ref(f"{_BUILD}:check_pointmaze"),
    ),
    "frozenlake": EnvKit(
        FrozenLakeSettings,
        Ref(f"{_BUILD}:frozenlake_data"),
        Ref(f"{_BUILD}:frozenlake_env"),
        Ref(f"{_BUILD}:frozenlake_evaluator"),
        action_projection=Ref(f"{_BUILD}:one_hot_argmax"),
    ),
    **{  # antmaze, locomotion, adroit: one data path, env and evaluator for every family
        kind: EnvKit(
            MINARI_SETTINGS[kind],
            Ref(f"{_MINARI}:minari_data"),
            Ref(f"{_MINARI}:minari_env"),
            Ref(f"{_MINARI}:minari_evaluator"),
            check=check_minari_dataset,
        )
        for kind in FAMILIES
    },
}
"""``env.kind`` -> :class:`EnvKit`."""
