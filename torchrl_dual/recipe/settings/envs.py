"""The table of environment kits, one entry per ``env.kind``, and their ``env.*`` schema.

An :class:`EnvKit` builds the data and the envs of Algorithm 1 line 1: it holds all the
recipe needs from one kind of environment, the schema of its ``env.*`` keys, the offline
data set ``D_offline``, the online env, the evaluator returning D4RL-normalized scores,
and the projection of the policy's action onto what the env executes. The builders are
references (:class:`~torchrl_dual.recipe.settings.lazy.Ref`) into :mod:`torchrl_dual.recipe.kits`
(``kits.pointmaze``, ``kits.frozenlake`` and, for the Minari families,
``kits.minari_families``), imported when a run starts. Adding an environment is adding
one entry to :data:`ENV_KITS`, its builders and one
``torchrl_dual/recipe/config/env/<name>.yaml`` that sets ``kind``; nothing else in the
recipe branches on the env.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.lazy import Ref
from torchrl_dual.recipe.settings.minari_datasets import FAMILIES, PROTOCOLS, check_minari_dataset
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
        load_data (callable): ``settings -> OfflineDataset``, ``D_offline`` (cached or read);
            ``settings`` is the run's :class:`~torchrl_dual.recipe.RecipeSettings`.
        make_env (callable): ``(settings, data) -> EnvBase``, the online env (the recipe appends
            :class:`~torchrl_dual.transforms.PreviousTransition` for Eq. 10's ``d_t``);
            ``data`` (``D_offline``, or ``None``: the kit reads it if it needs it) carries
            what the env must agree with (e.g. observation normalization).
        make_evaluator (callable): ``(settings, data) -> Evaluator``.
        action_projection (callable, optional): maps the sampled action to the executed
            one (stored in the replay buffer), e.g. the one-hot argmax of a discrete env.
        check (callable, optional): ``cfg -> None`` on the composed config, run by
            ``validate_config`` after the key checks; raises
            :class:`~torchrl_dual.recipe.settings.errors.ConfigError` for what the machine
            lacks (e.g. a Minari data set that is not on disk).

    Examples:
        >>> kit = ENV_KITS["frozenlake"]
        >>> kit.settings.__name__, kit.action_projection  # Frozen-Lake executes a one-hot action
        ('FrozenLakeSettings', Ref('torchrl_dual.recipe.kits.frozenlake:one_hot_argmax'))
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

    name: str = key(Text(), "used in `output_dir` and the plot title")
    kind: str = key(
        Text(),
        "the `ENV_KITS` entry (`torchrl_dual.recipe.ENV_KITS`) that builds the data, env and "
        "evaluator (the Minari families': `torchrl_dual/recipe/kits/minari_families.py`)",
    )
    max_episode_steps: int = key(
        Integer(1),
        "time limit of an episode, in steps (PointMaze: Gymnasium-Robotics' default, as D4RL "
        "maze2d; Frozen-Lake: also for `8x8`)",
    )
    critic_expectile: float = key(
        Real(0, 1, low_open=True, high_open=True),
        "the env family's preset of `critic.expectile` (IQL's `tau`), which reads it by "
        "interpolation (a value on the command line still wins): CORL's IQL `tau` for the "
        "family (PointMaze and Frozen-Lake: maze2d's)",
    )
    actor_temperature: float = key(
        Real(0, low_open=True),
        "the env family's preset of the algorithms' `actor.temperature` (`beta`), which reads "
        "it by interpolation (a value on the command line still wins): CORL's IQL `beta` for "
        "the family (PointMaze and Frozen-Lake: maze2d's)",
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

    maze: str = key(
        Choice(POINTMAZE_MAZES),
        "Gymnasium-Robotics layout: `PointMaze_UMaze-v3`, `PointMaze_Medium-v3`, "
        "`PointMaze_Large-v3`",
    )
    shift: str = key(
        Choice(SHIFTS_BY_KIND["pointmaze"]),
        "online-only dynamics shift of the online and evaluation envs (the data and their cache "
        "entry keep the unshifted env): `rotation` turns the action by `shift_angle`, `damping` "
        "and `mass` multiply the point's MuJoCo joint damping or mass by `shift_scale` "
        "([Online dynamics shifts](recipe.md#online-dynamics-shifts-envshift))",
    )
    shift_angle: float = key(
        Real(-180, 180),
        "degrees the actions are rotated by, counter-clockwise, under `shift=rotation` (before "
        "the env clips and executes them)",
    )
    shift_scale: Any = key(
        Maybe(Either((Real(0, 1000, low_open=True),), "must be a number in (0, 1000]")),
        "factor of MuJoCo `model.dof_damping` of the point's two slide joints (`shift=damping`) "
        "or of its `model.body_mass` (`shift=mass`); `null`: the shift's default, 150 for "
        "damping, 20 for mass",
    )
    goal_cell: Any = key(
        Maybe(IntegerList(0)),
        "`null`: each episode's goal is a random open cell (Gymnasium-Robotics), a "
        "goal-conditioned task; `[row, col]` (row 0 at the top): the goal always lies in that "
        "cell and only the start is random, as D4RL maze2d's one target per maze. It changes the "
        "task: the data (their own cache entry, `pointmaze-<maze>-goal<row>_<col>-...`), the "
        'online env and the evaluation use it. `torchrl_dual.envs.open_cells("medium")` lists '
        "the cells; a wall is an error that lists them",
    )
    data_avoid_cells: Any = key(
        Maybe(CellList()),
        "`[[row, col], ...]`: open cells the offline data never enter: the data controller plans "
        "around them as walls, an episode starting in one is reset, and only the action noise "
        'could push the point across their border (`metadata["avoided_fraction"]`, 0 in the '
        "tests). With `goal_cell` among them the data hold no reward, a task the online phase "
        "must explore, e.g. `env=pointmaze_medium env.goal_cell=[6,6] "
        "env.data_avoid_cells=[[4,6],[5,6],[6,5],[6,6]]` (Medium's bottom-right dead end: "
        "`algo=iql` trained on these data never reaches the goal, offline or online). Only the "
        "data change (their own cache entry, `...-avoid<row>_<col>-...`): the online env, the "
        "evaluation and the reference returns keep the whole maze, and episodes still start in "
        "these cells unless `start_avoid_cells` leaves them out",
    )
    start_avoid_cells: Any = key(
        Maybe(CellList()),
        "`[[row, col], ...]`: open cells where no online episode (each collector worker's env "
        "too) and no evaluation episode starts; `null`: any open cell but the goal's, as "
        "Gymnasium-Robotics. The starts' twin of `data_avoid_cells`: "
        "`env.start_avoid_cells=${env.data_avoid_cells}` keeps an exploration task's episodes "
        "from starting inside the region the data never enter (the Medium dead end of "
        "`data_avoid_cells`: 3 of the 25 start cells, one or two moves from the goal, about 12 % "
        "of episodes). The "
        'allowed cells become Gymnasium-Robotics\' reset cells (`"r"` in its `maze_map`; with a '
        'random goal `"c"`, the avoided cells staying goals): '
        "`torchrl_dual.envs.start_cells(maze, goal_cell, start_avoid_cells)` lists them, "
        "`torchrl_dual.recipe.kits.pointmaze.pointmaze_start_distances` reads how far they lie from "
        "the goal and from `data_avoid_cells`. A wall, an outside cell or no cell left to start "
        "in (with a random goal: fewer than 2) is an error. An online key: the data, the offline "
        "phase and its cache entry do not change; the normalized score's reference returns keep "
        "starts anywhere in the maze",
    )
    reward_scale: float = key(
        Real(0, low_open=True),
        "`r' = reward_scale · r + reward_shift` in the offline data and the online env (TorchRL "
        "`RewardScaling`); the evaluation and the reference returns read the env's own reward. "
        "The identity leaves the data's cache and every offline-cache key unchanged. The "
        "references' sparse-maze transforms: `algo=calql env.reward_scale=10 "
        "env.reward_shift=-5 critic.sparse_failure_reward=-5` (Cal-QL's AntMaze scripts), "
        "`env.reward_shift=-1` (CORL's IQL on AntMaze); the learning suite's `umaze_sparse` cell "
        "runs them",
    )
    reward_shift: float = key(
        Real(),
        "added after `reward_scale` (see there): CORL's IQL on AntMaze `-1`, Cal-QL's `-5`",
    )


# ----------------------------------------------------------------------------- Frozen-Lake
@dataclass
class FrozenLakeSettings(EnvSettings):
    """``env/frozenlake.yaml``: slippery Frozen-Lake with the paper's slip shift."""

    map_name: str = key(Choice(FROZENLAKE_MAPS), "the Frozen-Lake map")
    offline_success_rate: float = key(
        Real(0, 1, low_open=True),
        "probability of the intended move while the offline data are collected (slip: 1 − it)",
    )
    online_success_rate: float = key(
        Real(0, 1, low_open=True),
        "probability of the intended move online and at evaluation (slip: 1 − it); its "
        "difference from `offline_success_rate` is the paper's slip shift",
    )
    epsilon: float = key(
        Real(0, 1),
        "probability of a uniformly random action in the offline data's epsilon-greedy "
        "behaviour policy",
    )
    shift: str = key(
        Choice(SHIFTS_BY_KIND["frozenlake"]),
        "online-only dynamics shift on top of `online_success_rate`: `biased_slip`: every slip "
        "turns counter-clockwise of the intended move (left → down, down → right, right → up, "
        "up → left), never clockwise; `biased_slip_cw`: always clockwise "
        "([Online dynamics shifts](recipe.md#online-dynamics-shifts-envshift))",
    )


@dataclass
class MinariSettings(EnvSettings):
    """``env/antmaze.yaml``, ``env/hopper.yaml``, ...: a Minari data set and its env."""

    max_episode_steps: Any = key(
        Maybe(Integer(1)),
        "time limit in steps; `null`: the protocol's (`d4rl`: D4RL's, AntMaze 700 (U-maze) / "
        "1000, pen 100, door / hammer / relocate 200, locomotion 1000) or the data set's env "
        "spec; when set it wins over `protocol` and `horizon_seconds`",
    )
    dataset: str = key(
        Text(),
        "the data set's name in its Minari id (AntMaze `D4RL/antmaze/<dataset>-<dataset_version>`"
        ", locomotion `mujoco/<task>/...`, Adroit `D4RL/<task>/...`): AntMaze `umaze`, "
        "`umaze-diverse`, `medium-play`, `medium-diverse`, `large-play`, `large-diverse`; "
        "locomotion `medium`, `expert`, `simple`; Adroit `cloned`, `human`, `expert`; other "
        "Minari names are accepted. It must be on disk (`minari download <id>`, once); the "
        "online and evaluation envs are rebuilt from its env spec",
    )
    dataset_version: str = key(Text(), "Minari version suffix of the data set id")
    protocol: str = key(
        Choice(PROTOCOLS),
        "the task the envs pose: `d4rl`: D4RL's task, horizon and reference returns (as CORL and "
        "the paper); `minari`: the data set's own ([per family](recipe.md#env), "
        "[reproducing.md](reproducing.md#3-what-envprotocold4rl-does)); `max_episode_steps` "
        "and `reference_returns`, when set, win over it",
    )
    reward_scale: Any = key(
        Maybe(
            Either(
                (Real(0, low_open=True), Choice(("returns",))), "must be a number > 0 or 'returns'"
            )
        ),
        "`r' = reward_scale · r + reward_shift`, offline data and online env alike (the "
        "evaluation scores the env's own reward); `returns`: `T / (max − min)` of the data "
        "set's episode returns, `T` the time limit (CORL's `normalize_reward`); `null`: the "
        "critic's reference preset, `torchrl_dual.recipe.settings.references.REWARD_TRANSFORMS` "
        "([table](recipe.md#env)): IQL (DUAL and every algorithm on IQL's critic) and SO2 "
        "`r − 1` on AntMaze, `returns` on locomotion, `r` on Adroit; Cal-QL `10 r − 5` on "
        "AntMaze, `r` elsewhere",
    )
    reward_shift: Any = key(
        Maybe(Real()),
        "added after `reward_scale`; `null`: the critic's reference preset (see `reward_scale`)",
    )
    normalize_observations: bool = key(
        Flag(),
        "states → `(s − mean) / (std + 1e-3)` of the data set, in the data, the online env and "
        "the evaluation (CORL's IQL `normalize=True`); the preset "
        "`${reference:env.normalize_observations,true}` is `false` for `critic.name=calql` on "
        "AntMaze and Adroit (Cal-QL's references normalize no state: JaxCQL, CORL's Cal-QL "
        "`normalize: false`); a value on the command line wins",
    )
    reference_returns: Any = key(
        Maybe(RealList(2)),
        "`[random, expert]` returns of the normalized score, instead of the protocol's "
        "(`d4rl`: D4RL's) or the data set's `ref_min_score` / `ref_max_score`",
    )
    shift_scale: Any = key(
        Maybe(Real(0, low_open=True)),
        "level `s` of `shift` (unused by `none`); locomotion (ODRL): friction and gravity × `s`, "
        "a joint range or limb size / `s`; `null`: ODRL's 2.0, the paper's level (its `2.0` "
        "files for friction and gravity, its `medium` ones for kinematic and morphology), e.g. "
        "`env=halfcheetah env.shift=friction env.shift_scale=5.0`",
    )


@dataclass
class AntMazeSettings(MinariSettings):
    """``env/antmaze.yaml``: Minari ``D4RL/antmaze/<dataset>-<version>``."""

    shift: str = key(
        Choice(SHIFTS_BY_KIND["antmaze"]),
        "online-only dynamics shift of the online and evaluation envs; AntMaze has none but "
        "`none` ([Online dynamics shifts](recipe.md#online-dynamics-shifts-envshift))",
    )
    goal_noise: bool = key(
        Flag(),
        "`protocol=d4rl`: `false` keeps D4RL's goal fixed at the centre of its goal square; "
        "`true` redraws it in that 1.5 × 1.5 square at each reset, as D4RL's `-v2` envs do (the "
        "data stay relabelled to the centre)",
    )
    horizon_seconds: Any = key(
        Maybe(
            Either((Real(0, low_open=True), Choice(("d4rl",))), "must be a number > 0 or 'd4rl'")
        ),
        "time limit in simulated seconds, at the data's ant step of 0.05 s (Gymnasium-Robotics' "
        "timestep 0.01 × frame skip 5; D4RL's ant steps 0.1 s); `d4rl`: D4RL's 70 s (umaze) / "
        "100 s, i.e. 1400 / 2000 steps here; `null`: the protocol's step count (700 / 1000 "
        "steps, 35 / 50 s here); `max_episode_steps` wins "
        "([reproducing.md](reproducing.md#4-what-still-differs-from-the-papers-setup))",
    )


@dataclass
class LocomotionSettings(MinariSettings):
    """``env/hopper.yaml``, ``halfcheetah.yaml``, ``walker2d.yaml``: MuJoCo locomotion.

    Minari ``mujoco/<task>/<dataset>-<version>`` and the ODRL shifts.
    """

    task: str = key(
        Choice(FAMILIES["locomotion"].tasks),
        "the robot, `<task>` in `mujoco/<task>/<dataset>-<dataset_version>`: env `Hopper-v5`, "
        "`HalfCheetah-v5` or `Walker2d-v5` (MuJoCo v5 via Gymnasium); `env=hopper`, "
        "`halfcheetah`, `walker2d` set it",
    )
    shift: str = key(
        Choice(SHIFTS_BY_KIND["locomotion"]),
        "online-only ODRL dynamics shift of the online and evaluation envs (never of the data) "
        "at level `shift_scale`: `friction` scales the geoms' friction, `gravity` the gravity, "
        "`kinematic` narrows a joint's range, `morphology` shrinks a limb "
        "([ODRL shifts](recipe.md#odrl-shifts-mujoco-locomotion)), e.g. `env=hopper "
        "env.shift=kinematic`",
    )


@dataclass
class AdroitSettings(MinariSettings):
    """``env/adroit.yaml``: Minari ``D4RL/<task>/<dataset>-<version>``."""

    task: str = key(
        Choice(FAMILIES["adroit"].tasks),
        "the Adroit hand task, `<task>` in `D4RL/<task>/<dataset>-<dataset_version>`: env "
        "`AdroitHand*-v1` (Gymnasium-Robotics), e.g. `env=adroit env.task=door env.dataset=human`",
    )
    shift: str = key(
        Choice(SHIFTS_BY_KIND["adroit"]),
        "online-only dynamics shift of the online and evaluation envs; Adroit has none but "
        "`none` ([Online dynamics shifts](recipe.md#online-dynamics-shifts-envshift))",
    )


MINARI_SETTINGS: dict[str, type] = {
    "antmaze": AntMazeSettings,
    "locomotion": LocomotionSettings,
    "adroit": AdroitSettings,
}


# ----------------------------------------------------------------------------- the table
_POINTMAZE = "torchrl_dual.recipe.kits.pointmaze"
_FROZENLAKE = "torchrl_dual.recipe.kits.frozenlake"
_MINARI = "torchrl_dual.recipe.kits.minari_families"

ENV_KITS: dict[str, EnvKit] = {
    "pointmaze": EnvKit(
        PointMazeSettings,
        Ref(f"{_POINTMAZE}:pointmaze_data"),
        Ref(f"{_POINTMAZE}:pointmaze_env"),
        Ref(f"{_POINTMAZE}:pointmaze_evaluator"),
        check=Ref(f"{_POINTMAZE}:check_pointmaze"),
    ),
    "frozenlake": EnvKit(
        FrozenLakeSettings,
        Ref(f"{_FROZENLAKE}:frozenlake_data"),
        Ref(f"{_FROZENLAKE}:frozenlake_env"),
        Ref(f"{_FROZENLAKE}:frozenlake_evaluator"),
        action_projection=Ref(f"{_FROZENLAKE}:one_hot_argmax"),
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
