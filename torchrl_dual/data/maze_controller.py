"""D4RL-style maze2d data-collection controller: BFS over the grid + noisy PD waypoints.

The maze grid (Gymnasium-Robotics ``maze_map``: 1 = wall) is solved once with a
breadth-first search from every free cell, giving a next-hop table. At each step the
controller aims at the centre of the next cell on the shortest path to its goal (at the
goal itself once in the goal cell) with the D4RL gains ``action = p * (waypoint - pos) +
d * vel`` (``p=10``, ``d=-1``), adds Gaussian action noise and clips to ``[-1, 1]``.
Aiming from anywhere in a cell at the centre of an adjacent free cell keeps the segment
inside the union of the two cells, so the point never cuts a wall corner by design.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np


class MazeWaypointController:
    """Shortest-path waypoint controller for a point mass in a grid maze.

    Args:
        maze_map (sequence of sequences): the Gymnasium-Robotics map; ``1`` marks walls,
            anything else (``0``, ``"g"``, ``"r"``, ``"c"``) is free.

    Keyword Args:
        maze_size_scaling (float): cell size in world units (1 for PointMaze).
        p_gain (float): proportional gain. Defaults to ``10.0`` (D4RL).
        d_gain (float): velocity gain. Defaults to ``-1.0`` (D4RL).
        action_noise (float): std of the Gaussian action noise. Defaults to ``0.5``
            (D4RL ``--noisy``).
        rng (np.random.Generator, optional): random source for noise and goals.
        avoid_cells (sequence of (row, col), optional): free cells the controller plans
            around as if they were walls: it never picks a goal there, routes around them
            and, if noise pushes it into one, heads back to the nearest allowed cell (data
            that leave a region unvisited, issue 29). Defaults to none.

    Examples:
        >>> from gymnasium_robotics.envs.maze.maps import U_MAZE
        >>> ctrl = MazeWaypointController(U_MAZE, action_noise=0.0)
        >>> ctrl.num_free_cells
        7
        >>> ctrl.path_length(ctrl.xy_to_cell(np.array([1.0, 1.0])), ctrl.xy_to_cell(np.array([-1.0, -1.0])))
        4
        >>> ctrl.act(np.array([1.0, 1.0]), np.zeros(2), np.array([-1.0, -1.0]))  # down the right arm
        array([ 0., -1.])
    """

    def __init__(
        self,
        maze_map: Sequence[Sequence[int | str]],
        *,
        maze_size_scaling: float = 1.0,
        p_gain: float = 10.0,
        d_gain: float = -1.0,
        action_noise: float = 0.5,
        rng: np.random.Generator | None = None,
        avoid_cells: Sequence[Sequence[int]] = (),
    ) -> None:
        walls = np.array([[cell == 1 for cell in row] for row in maze_map], dtype=bool)
        self.avoided = {(int(r), int(c)) for r, c in avoid_cells}
        for cell in self.avoided:
            if not (0 <= cell[0] < walls.shape[0] and 0 <= cell[1] < walls.shape[1]):
                raise ValueError(f"avoid_cells: {list(cell)} is outside the {walls.shape} maze.")
            if walls[cell]:
                raise ValueError(f"avoid_cells: {list(cell)} is a wall, not a free cell.")
            walls[cell] = True  # planned around as a wall
        if not (~walls).any():
            raise ValueError("avoid_cells covers every free cell; leave some to move in.")
        self.walls = walls
        self.rows, self.cols = walls.shape
        self.scaling = float(maze_size_scaling)
        self.x_center = self.cols / 2 * self.scaling
        self.y_center = self.rows / 2 * self.scaling
        self.p_gain, self.d_gain = float(p_gain), float(d_gain)
        self.action_noise = float(action_noise)
        self.rng = rng if rng is not None else np.random.default_rng()
        free = np.argwhere(~walls)
        self.free_cells = [tuple(int(v) for v in rc) for rc in free]
        self.num_free_cells = len(self.free_cells)
        self._centres = {rc: self.cell_to_xy(rc) for rc in self.free_cells}
        self._next_hop, self._dist = self._solve()

    def _solve(self) -> tuple[dict, dict]:
        """BFS from every free cell: ``next_hop[(cell, goal)]`` and ``dist[(cell, goal)]``."""
        next_hop: dict = {}
        dist: dict = {}
        for goal in self.free_cells:
            dist[(goal, goal)] = 0
            next_hop[(goal, goal)] = goal
            queue = deque([goal])
            while queue:
                cell = queue.popleft()
                r, c = cell
                for nb in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)):
                    if (
                        0 <= nb[0] < self.rows
                        and 0 <= nb[1] < self.cols
                        and not self.walls[nb]
                        and (nb, goal) not in dist
                    ):
                        dist[(nb, goal)] = dist[(cell, goal)] + 1
                        next_hop[(nb, goal)] = cell  # from nb, step towards the goal via cell
                        queue.append(nb)
        return next_hop, dist

    def cell_to_xy(self, cell: tuple[int, int]) -> np.ndarray:
        """World coordinates of a cell centre (Gymnasium-Robotics convention)."""
        r, c = cell
        return np.array(
            [(c + 0.5) * self.scaling - self.x_center, self.y_center - (r + 0.5) * self.scaling]
        )

    def xy_to_cell(self, xy: np.ndarray) -> tuple[int, int]:
        """Free cell containing ``xy`` (the nearest free cell if ``xy`` grazes a wall)."""
        r = math.floor((self.y_center - float(xy[1])) / self.scaling)
        c = math.floor((float(xy[0]) + self.x_center) / self.scaling)
        if 0 <= r < self.rows and 0 <= c < self.cols and not self.walls[r, c]:
            return (r, c)
        # in a wall's margin or an avoided cell: the nearest allowed cell (heads back out)
        return min(self.free_cells, key=lambda rc: float(np.sum((self._centres[rc] - xy) ** 2)))

    def path_length(self, cell: tuple[int, int], goal: tuple[int, int]) -> int:
        """Number of cell moves on the shortest path (``-1`` if unreachable)."""
        return self._dist.get((cell, goal), -1)

    def random_goal(
        self, exclude: tuple[int, int] | None = None
    ) -> tuple[tuple[int, int], np.ndarray]:
        """Draws a random reachable free cell (not ``exclude``) and a point near its centre.

        The point gets the same uniform jitter (±0.25 cell) as Gymnasium-Robotics goals.
        """
        while True:
            cell = self.free_cells[int(self.rng.integers(self.num_free_cells))]
            if cell != exclude and (exclude is None or self.path_length(exclude, cell) > 0):
                break
        jitter = self.rng.uniform(-0.25, 0.25, size=2) * self.scaling
        return cell, self._centres[cell] + jitter

    def waypoint(self, position: np.ndarray, goal_xy: np.ndarray) -> np.ndarray:
        """Next target point: the centre of the next cell on the path, or the goal itself."""
        cell = self.xy_to_cell(position)
        goal_cell = self.xy_to_cell(goal_xy)
        if cell == goal_cell:
            return goal_xy
        hop = self._next_hop.get((cell, goal_cell))
        if hop is None:  # unreachable goal: head straight for it
            return goal_xy
        return self._centres[hop]

    def act(
        self,
        position: np.ndarray,
        velocity: np.ndarray,
        goal_xy: np.ndarray,
        noise: np.ndarray | None = None,
    ) -> np.ndarray:
        """PD action towards the current waypoint, plus noise, clipped to ``[-1, 1]``.

        Args:
            position (np.ndarray): ``(x, y)``.
            velocity (np.ndarray): ``(vx, vy)``.
            goal_xy (np.ndarray): the point to reach.
            noise (np.ndarray, optional): pre-drawn standard normal noise ``(2,)``; drawn
                from ``rng`` if ``None``. It is scaled by ``action_noise``.
        """
        target = self.waypoint(position, goal_xy)
        action = self.p_gain * (target - position) + self.d_gain * velocity
        if self.action_noise > 0:
            if noise is None:
                noise = self.rng.standard_normal(2)
            action = action + self.action_noise * noise
        return np.clip(action, -1.0, 1.0)
