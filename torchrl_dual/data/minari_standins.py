"""Stand-in Minari data sets: tiny random-action data under the published ids.

They carry the published env versions and metadata fields, for machines that cannot download
the published data sets (tests, CI, benchmarks of the code paths).

:data:`STANDINS` maps a published id to how its env is made, after Farama-Foundation's
minari-dataset-generation-scripts (``scripts/D4RL/antmaze/create_antmaze_dataset.py``,
the Adroit scripts): ``D4RL/antmaze/umaze-v1`` is ``AntMaze_UMaze-v4`` with D4RL's U-maze
map upside down (goal top left, reset bottom left), ``continuing_task=True``,
``reset_target=False``, and the scripts' evaluation env (start and goal on the right-hand
column); ``umaze-diverse``, ``medium-*`` and ``large-*`` are the registered
``AntMaze_UMaze-v4``, ``AntMaze_Medium-v4`` / ``AntMaze_Medium_Diverse_GR-v4``,
``AntMaze_Large-v4`` / ``AntMaze_Large_Diverse_GR-v4`` with the scripts' evaluation maps
(D4RL's ``*_TEST`` maps); ``mujoco/<robot>/medium-v0`` are the v5 MuJoCo envs without
references (Minari's MuJoCo data sets are not D4RL imports); ``D4RL/<task>/cloned-v2`` are
``AdroitHand<Task>-v1`` at the registered time limit (200) the published sets record,
with references. The reference values
are stand-ins of the right kind (random < expert), not the published numbers, and the data
is uniform random actions: it exercises loading, flattening, boundaries, envs and scores,
not learning.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym

from torchrl_dual.data.minari_writer import collect_episodes, write_minari_dataset
from torchrl_dual.envs.d4rl_antmaze import D4RL_ANTMAZE_MAPS
from torchrl_dual.envs.maze_xml import release_maze_xml
from torchrl_dual.envs.robotics import register_robotics_envs

R, G = "r", "g"
UMAZE_MAP = [[1, 1, 1, 1, 1], [1, G, 0, 0, 1], [1, 1, 1, 0, 1], [1, R, 0, 0, 1], [1, 1, 1, 1, 1]]
"""D4RL's ``antmaze-umaze`` map (data collection): goal top left, reset bottom left."""
UMAZE_EVAL_MAP = [
    [1, 1, 1, 1, 1],
    [1, 0, 0, R, 1],
    [1, 0, 1, 1, 1],
    [1, 0, 0, G, 1],
    [1, 1, 1, 1, 1],
]
"""The evaluation map the Minari AntMaze data sets record."""


@dataclass(frozen=True)
class StandIn:
    """How the env of one published data set is made.

    Args:
        env_id (str): the Gymnasium id the published data set records.
        kwargs (dict): its ``gym.make`` kwargs.
        eval_kwargs (dict, optional): kwargs that differ in its evaluation env.
        references (tuple of float, optional): stand-in ``(ref_min_score, ref_max_score)``.
    """

    env_id: str
    kwargs: dict[str, Any] = field(default_factory=dict)
    eval_kwargs: dict[str, Any] | None = None
    references: tuple[float, float] | None = None


_ANTMAZE = {"continuing_task": True, "reset_target": False}
_D4RL_EVAL = {  # the generation scripts' EVAL_ENV_MAPS: D4RL's *_TEST maps, rows as they are
    maze: {"maze_map": [[c.lower() if isinstance(c, str) else c for c in row] for row in rows]}
    for maze, rows in D4RL_ANTMAZE_MAPS.items()
}

STANDINS: dict[str, StandIn] = {
    "D4RL/antmaze/umaze-v1": StandIn(
        "AntMaze_UMaze-v4",
        {"maze_map": UMAZE_MAP, **_ANTMAZE},
        {"maze_map": UMAZE_EVAL_MAP},
        (0.0, 400.0),
    ),
    # the registered maps: no r/g/c cells (play: goals and starts anywhere) or c cells (diverse)
    "D4RL/antmaze/umaze-diverse-v1": StandIn(
        "AntMaze_UMaze-v4", dict(_ANTMAZE), {"maze_map": UMAZE_EVAL_MAP}, (0.0, 400.0)
    ),
    "D4RL/antmaze/medium-play-v1": StandIn(
        "AntMaze_Medium-v4", dict(_ANTMAZE), _D4RL_EVAL["medium"], (0.0, 600.0)
    ),
    "D4RL/antmaze/medium-diverse-v1": StandIn(
        "AntMaze_Medium_Diverse_GR-v4", dict(_ANTMAZE), _D4RL_EVAL["medium"], (0.0, 600.0)
    ),
    "D4RL/antmaze/large-play-v1": StandIn(
        "AntMaze_Large-v4", dict(_ANTMAZE), _D4RL_EVAL["large"], (0.0, 600.0)
    ),
    "D4RL/antmaze/large-diverse-v1": StandIn(
        "AntMaze_Large_Diverse_GR-v4", dict(_ANTMAZE), _D4RL_EVAL["large"], (0.0, 600.0)
    ),
    "mujoco/hopper/medium-v0": StandIn("Hopper-v5"),
    "mujoco/halfcheetah/medium-v0": StandIn("HalfCheetah-v5"),
    "mujoco/walker2d/medium-v0": StandIn("Walker2d-v5"),
    "D4RL/pen/cloned-v2": StandIn("AdroitHandPen-v1", references=(96.26, 3076.83)),
    # the published sets record the registered time limit, 200 (Minari's data set pages,
    # "Environment Specs": max_episode_steps 200), not the generation scripts' 300 / 625 / 530
    "D4RL/door/cloned-v2": StandIn("AdroitHandDoor-v1", references=(-56.51, 2880.57)),
    "D4RL/hammer/cloned-v2": StandIn("AdroitHandHammer-v1", references=(-274.86, 12794.13)),
    "D4RL/relocate/cloned-v2": StandIn("AdroitHandRelocate-v1", references=(-6.43, 4233.88)),
}
"""Published Minari id -> :class:`StandIn`."""


def write_standin_dataset(
    dataset_id: str, num_episodes: int = 4, steps: int = 40, *, seed: int = 0
):
    """Writes a random-action stand-in for ``dataset_id`` into ``MINARI_DATASETS_PATH``.

    Args:
        dataset_id (str): a key of :data:`STANDINS`.
        num_episodes (int): episodes. Defaults to 4.
        steps (int): cut each episode after this many steps (truncated). Defaults to 40.

    Keyword Args:
        seed (int): episode ``k`` is reset with ``seed + k``.

    Returns:
        the ``minari.MinariDataset``.

    Examples:
        >>> import os, tempfile
        >>> os.environ["MINARI_DATASETS_PATH"] = tempfile.mkdtemp()
        >>> dataset = write_standin_dataset("mujoco/hopper/medium-v0", 2, 10)
        >>> dataset.env_spec.id, dataset.total_steps <= 20
        ('Hopper-v5', True)
    """
    if dataset_id not in STANDINS:
        raise ValueError(f"no stand-in for {dataset_id!r}; known: {sorted(STANDINS)}.")
    register_robotics_envs()
    standin = STANDINS[dataset_id]
    env = release_maze_xml(gym.make(standin.env_id, **standin.kwargs))
    eval_spec = None
    if standin.eval_kwargs is not None:
        eval_env = gym.make(standin.env_id, **{**standin.kwargs, **standin.eval_kwargs})
        eval_spec = release_maze_xml(eval_env).spec
    buffers = collect_episodes(env, None, num_episodes, seed=seed, max_steps=steps)
    env.close()
    return write_minari_dataset(
        dataset_id,
        buffers,
        env.spec,
        eval_env_spec=eval_spec,
        reference_returns=standin.references,
        algorithm_name="torchrl_dual stand-in (uniform random actions)",
    )
