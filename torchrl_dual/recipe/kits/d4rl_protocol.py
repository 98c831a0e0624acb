"""``env.protocol``: what a Minari data set's run changes to follow D4RL's protocol, per family.

D4RL's protocol is also CORL's and the paper's.

=============  ============================================  =================================
family         ``protocol=d4rl`` (default)                   ``protocol=minari``
=============  ============================================  =================================
AntMaze        D4RL's single-goal task in the data's maze     Minari's goal-conditioned task:
               (:class:`~torchrl_dual.envs.SingleGoalAntMaze`  ``desired_goal`` observed, goal
               online and in evaluation, rewards and          per episode, radius 0.45, never
               terminals relabelled to its goal,              ends, evaluation in the data set's
               ``desired_goal`` not observed, D4RL's          ``eval_env`` (whose U-maze is
               horizon), score 100 x success rate             turned, Minari issue #304)
Adroit         D4RL's horizon (pen 100, others 200), its      the data set's env spec and
               references, Pen's end when the pen drops       references
               (:class:`~torchrl_dual.envs.PenDropTermination`)
locomotion     D4RL's random / expert references              none (no normalized score)
=============  ============================================  =================================

``env.max_episode_steps`` and ``env.reference_returns``, when set, win over both; AntMaze's
``env.horizon_seconds`` sets the time limit in simulated seconds (:func:`horizon_of_seconds`:
D4RL's ant steps 0.1 s, the data's 0.05 s) and ``env.goal_noise`` redraws D4RL's goal at
each reset.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

from torchrl_dual.data.d4rl_references import D4RL_HORIZONS, d4rl_references
from torchrl_dual.envs import register_robotics_envs, release_maze_xml
from torchrl_dual.envs.d4rl_antmaze import D4RLAntMazeTask, d4rl_horizon_seconds, d4rl_maze_of
from torchrl_dual.recipe.settings.envs import MinariSettings
from torchrl_dual.recipe.settings.errors import UserError
from torchrl_dual.recipe.settings.minari_datasets import FAMILIES

ANTMAZE_D4RL_OBSERVATION_KEYS = ["achieved_goal", "observation"]
"""D4RL's 29 AntMaze numbers (torso x, y, then Minari's ``observation``), no goal."""


@dataclass(frozen=True)
class DataProtocol:
    """What ``env.protocol`` sets for one data set.

    Args:
        name (str): ``d4rl`` or ``minari``.
        observation_keys (list of str, optional): dict entries the policy sees (``None``:
            :func:`~torchrl_dual.data.default_observation_keys`).
        max_episode_steps (int, optional): time limit (``None``: the data set's env spec).
        references (tuple of float, optional): ``(random, expert)`` returns (``None``: the
            data set's).
        antmaze_task (D4RLAntMazeTask, optional): D4RL's single AntMaze goal.
        evaluate_in_eval_env (bool): evaluate in the data set's ``eval_env`` rather than
            the env of its data.
        pen_drop_ends (bool): a Pen episode ends when the pen drops (D4RL's pen).
    """

    name: str
    observation_keys: list[str] | None = None
    max_episode_steps: int | None = None
    references: tuple[float, float] | None = None
    antmaze_task: D4RLAntMazeTask | None = None
    evaluate_in_eval_env: bool = False
    pen_drop_ends: bool = False


@functools.lru_cache(maxsize=8)
def _antmaze_task(dataset_id: str, dataset: str) -> D4RLAntMazeTask:
    import minari

    register_robotics_envs()
    env = release_maze_xml(minari.load_dataset(dataset_id).recover_environment())
    maze = env.unwrapped.maze
    try:
        return D4RLAntMazeTask.for_maze(
            d4rl_maze_of(dataset), maze.maze_map, maze_size_scaling=maze.maze_size_scaling
        )
    except ValueError as err:
        raise UserError("env.protocol", "d4rl", f"{dataset_id}: {err}") from err
    finally:
        env.close()


def data_protocol(env: MinariSettings) -> DataProtocol:
    """The :class:`DataProtocol` of a Minari family's ``env`` section."""
    if env.protocol == "minari":
        return DataProtocol("minari", evaluate_in_eval_env=True)
    dataset_id = FAMILIES[env.kind].dataset_id(env)
    if env.kind == "antmaze":
        task = _antmaze_task(dataset_id, env.dataset)
        return DataProtocol(
            "d4rl",
            observation_keys=list(ANTMAZE_D4RL_OBSERVATION_KEYS),
            max_episode_steps=task.max_episode_steps,
            references=d4rl_references("antmaze"),
            antmaze_task=task,
        )
    return DataProtocol(
        "d4rl",
        max_episode_steps=D4RL_HORIZONS[env.task],
        references=d4rl_references(env.task),
        pen_drop_ends=getattr(env, "task", None) == "pen",
    )


@functools.lru_cache(maxsize=8)
def ant_step_seconds(dataset_id: str) -> float:
    """Simulated seconds per step of the ant of a Minari AntMaze data set's env."""
    import minari

    register_robotics_envs()
    env = release_maze_xml(minari.load_dataset(dataset_id).recover_environment())
    try:
        return float(env.unwrapped.ant_env.dt)
    finally:
        env.close()


def horizon_of_seconds(env: MinariSettings) -> int | None:
    """The time limit in steps that ``env.horizon_seconds`` gives (AntMaze), or ``None`` if unset.

    The seconds (``d4rl``: D4RL's, 0.1 s x 700 / 1000) at the data's env step.
    """
    seconds = getattr(env, "horizon_seconds", None)
    if seconds is None:
        return None
    if seconds == "d4rl":
        seconds = d4rl_horizon_seconds(env.dataset)
    step = ant_step_seconds(FAMILIES[env.kind].dataset_id(env))
    return max(1, round(float(seconds) / step))


def protocol_metadata(protocol: DataProtocol) -> dict[str, Any]:
    """What the run's data record says of its protocol (JSON-serializable)."""
    meta: dict[str, Any] = {"protocol": protocol.name}
    if protocol.antmaze_task is not None:
        meta["task_goal"] = protocol.antmaze_task.goal.tolist()
        meta["task_reset_cell"] = list(protocol.antmaze_task.reset_cell)
    return meta
