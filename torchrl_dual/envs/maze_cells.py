"""The PointMaze layouts' cells: which are open, and the goal and start cells of a task.

Row 0 is the top row of a Gymnasium-Robotics ``maze_map`` (1 a wall); a cell is a
``(row, col)`` pair. :func:`goal_maze_map` and :func:`start_cells` check the cells a
config names, and the env factories of :mod:`~torchrl_dual.envs.pointmaze` build their
``maze_map`` from them.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import gymnasium as gym

from torchrl_dual.envs.robotics import register_robotics_envs

POINTMAZE_IDS: dict[str, str] = {
    "umaze": "PointMaze_UMaze-v3",
    "medium": "PointMaze_Medium-v3",
    "large": "PointMaze_Large-v3",
}
"""Maze name -> Gymnasium-Robotics environment id."""


def pointmaze_env_id(maze: str) -> str:
    """Returns the Gymnasium id of a PointMaze layout.

    Args:
        maze (str): one of ``"umaze"``, ``"medium"``, ``"large"`` (case-insensitive).

    Raises:
        ValueError: for an unknown maze name; the message lists the valid names.

    Examples:
        >>> pointmaze_env_id("umaze")
        'PointMaze_UMaze-v3'
    """
    key = maze.lower() if isinstance(maze, str) else maze
    if key not in POINTMAZE_IDS:
        raise ValueError(
            f"Unknown PointMaze layout {maze!r}. Valid names: {sorted(POINTMAZE_IDS)}."
        )
    return POINTMAZE_IDS[key]


def open_cells(maze: str) -> list[tuple[int, int]]:
    """The ``(row, col)`` cells of a layout that are not walls, in reading order.

    Args:
        maze (str): a layout of :data:`POINTMAZE_IDS`.

    Returns:
        list[tuple[int, int]]: the open cells.

    Examples:
        >>> open_cells("umaze")
        [(1, 1), (1, 2), (1, 3), (2, 3), (3, 1), (3, 2), (3, 3)]
    """
    return [
        (i, j) for i, row in enumerate(_maze_map(maze)) for j, cell in enumerate(row) if cell != 1
    ]


def _maze_map(maze: str) -> list[list[Any]]:
    """A copy of the layout's registered Gymnasium-Robotics ``maze_map`` (1 = wall)."""
    register_robotics_envs()
    return [list(row) for row in gym.spec(pointmaze_env_id(maze)).kwargs["maze_map"]]


def goal_maze_map(maze: str, goal_cell: Sequence[int]) -> list[list[Any]]:
    """The layout's Gymnasium-Robotics ``maze_map`` with ``goal_cell`` as its only goal cell.

    The goal cell is marked ``"g"``: every episode's goal lies there, resets stay random
    among the other open cells.

    Args:
        maze (str): a layout of :data:`POINTMAZE_IDS`.
        goal_cell (sequence of int): the ``(row, col)`` goal cell.

    Returns:
        list[list]: the ``maze_map`` (1 wall, 0 open, ``"g"`` the goal).

    Raises:
        ValueError: ``goal_cell`` is not a ``(row, col)`` pair of an open cell; the message
            lists the open cells.

    Examples:
        >>> goal_maze_map("umaze", (3, 1))[3]
        [1, 'g', 0, 0, 1]
    """
    row, col = _open_cell(maze, goal_cell, "goal_cell")
    maze_map = _maze_map(maze)
    maze_map[row][col] = "g"
    return maze_map


def _open_cell(maze: str, cell: Sequence[int], name: str) -> tuple[int, int]:
    """``cell`` as a ``(row, col)`` tuple, checked to be an open cell.

    Raises a ``ValueError`` listing the open cells unless it is one.
    """
    cells = open_cells(maze)
    if tuple(cell) not in cells:
        raise ValueError(
            f"{name} {list(cell)} is not an open cell of the {maze} maze (a "
            f"[row, col] pair, row 0 at the top); open cells: {[list(c) for c in cells]}."
        )
    return (int(cell[0]), int(cell[1]))


def start_cells(
    maze: str,
    goal_cell: Sequence[int] | None = None,
    start_avoid_cells: Sequence[Sequence[int]] | None = None,
) -> list[tuple[int, int]]:
    """The cells, in reading order, where an episode of a PointMaze env starts.

    For an env made with ``goal_cell`` and ``start_avoid_cells``, each cell is as likely
    as the others (Gymnasium-Robotics' uniform reset cell, plus its noise of up to a
    quarter cell): the open cells but ``goal_cell`` and ``start_avoid_cells``. With a
    random goal per episode (``goal_cell=None``) an episode never starts in its own
    goal's cell either.

    Args:
        maze (str): a layout of :data:`POINTMAZE_IDS`.
        goal_cell (sequence of int, optional): the fixed goal cell; a random goal per
            episode if omitted.
        start_avoid_cells (sequence of cells, optional): cells no episode starts in.

    Returns:
        list[tuple[int, int]]: the start cells, equally likely.

    Raises:
        ValueError: a ``start_avoid_cells`` entry is not an open cell, or they leave no
            start cell (with a random goal, fewer than two: a start must differ from the
            episode's goal cell); the message lists the open cells.

    Examples:
        >>> start_cells("umaze", goal_cell=(3, 1), start_avoid_cells=[(3, 2)])
        [(1, 1), (1, 2), (1, 3), (2, 3), (3, 3)]
        >>> start_cells("umaze", goal_cell=(3, 1)) == start_cells("umaze", (3, 1), None)
        True
    """
    avoided = {
        _open_cell(maze, cell, "start_avoid_cells entry") for cell in start_avoid_cells or ()
    }
    if goal_cell is not None:
        avoided.add(_open_cell(maze, goal_cell, "goal_cell"))
    cells = [cell for cell in open_cells(maze) if cell not in avoided]
    needed = 1 if goal_cell is not None else 2  # a random goal may fall in the one left
    if len(cells) < needed:
        problem = (
            f"and goal_cell leave no open cell of the {maze} maze to start an episode in"
            if needed == 1
            else f"leave {len(cells)} open cell(s) of the {maze} maze to start an episode in; "
            "with a random goal per episode (goal_cell null) at least 2 are needed, as a start "
            "must differ from the goal's cell"
        )
        raise ValueError(
            f"start_avoid_cells {problem}. Open cells: {[list(c) for c in open_cells(maze)]}."
        )
    return cells


def task_maze_map(
    maze: str,
    goal_cell: Sequence[int] | None,
    start_avoid_cells: Sequence[Sequence[int]] | None,
) -> list[list[Any]]:
    """The ``maze_map`` given to Gymnasium-Robotics, with goal and reset cells marked.

    ``goal_cell`` is marked ``"g"`` (:func:`goal_maze_map`) and, with
    ``start_avoid_cells``, the start cells are marked reset cells (``"r"``; ``"c"``,
    goal or reset, with a random goal, the avoided cells then ``"g"``: every open cell
    stays a possible goal).
    """
    maze_map = _maze_map(maze) if goal_cell is None else goal_maze_map(maze, goal_cell)
    if start_avoid_cells:
        starts = set(start_cells(maze, goal_cell, start_avoid_cells))
        for row, col in open_cells(maze):
            if (row, col) in starts:
                maze_map[row][col] = "r" if goal_cell is not None else "c"
            elif goal_cell is None:
                maze_map[row][col] = "g"
    return maze_map


def default_max_episode_steps(maze: str) -> int:
    """Evaluation episode length registered by Gymnasium-Robotics for a layout.

    Args:
        maze (str): a layout of :data:`POINTMAZE_IDS`.

    Returns:
        int: the registered ``max_episode_steps``.

    Examples:
        >>> default_max_episode_steps("umaze"), default_max_episode_steps("large")
        (300, 800)
    """
    register_robotics_envs()
    return int(gym.spec(pointmaze_env_id(maze)).max_episode_steps)
