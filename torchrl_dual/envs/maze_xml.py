"""Deletes the model file that Gymnasium-Robotics leaves in the temp dir for every maze env.

Gymnasium-Robotics 1.4 (``envs/maze/maze_v4.py``, ``Maze.make_maze``) writes each PointMaze
or AntMaze env's MuJoCo model to ``<tempdir>/ant_maze<time>.xml``, next to (not inside) a
``TemporaryDirectory``, so the file outlives the env: a run that builds envs for its data,
its collector workers and each evaluation leaves hundreds of them behind. MuJoCo has read
the file when the env's constructor returns, so :func:`release_maze_xml` deletes it then.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from typing import TypeVar

EnvT = TypeVar("EnvT")


def release_maze_xml(env: EnvT) -> EnvT:
    """Deletes the temp model file of a Gymnasium-Robotics maze ``env`` and returns ``env``.

    ``env`` may be any wrapper of it; other envs are returned untouched.

    Args:
        env (gym.Env): any env.

    Returns:
        ``env`` itself.

    Examples:
        >>> import os
        >>> from torchrl_dual.envs import make_pointmaze_gym_env
        >>> env = make_pointmaze_gym_env("umaze", max_episode_steps=5)  # released inside
        >>> os.path.exists(env.unwrapped.tmp_xml_file_path)
        False
        >>> _ = env.reset(seed=0)
    """
    path = getattr(getattr(env, "unwrapped", None), "tmp_xml_file_path", None)
    if isinstance(path, str) and _is_maze_temp_file(path):
        with contextlib.suppress(FileNotFoundError):
            os.remove(path)
    return env


def _is_maze_temp_file(path: str) -> bool:
    """Only the file ``Maze.make_maze`` wrote: ``ant_maze*.xml`` directly in the temp dir."""
    name = os.path.basename(path)
    in_temp = os.path.dirname(os.path.abspath(path)) == os.path.abspath(tempfile.gettempdir())
    return in_temp and name.startswith("ant_maze") and name.endswith(".xml")
