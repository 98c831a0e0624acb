"""D4RL's single-goal AntMaze task on Minari's data and Gymnasium-Robotics' env.

Posed on Minari's AntMaze data and Gymnasium-Robotics' AntMaze env (``env.protocol=d4rl``).

D4RL's and CORL's AntMaze is one task per maze: the ant always starts in the map's reset
cell ``R``, must reach one fixed goal near the map's goal cell ``G``, sees no goal in its
observation (29 numbers: ``qpos[:15]``, ``qvel[:14]``), earns reward 1 within 0.5 of the
goal, and an evaluation episode ends there, so the normalized score is 100 x the success
rate (``ref_min_score = 0``, ``ref_max_score = 1``). Minari's port records goal-conditioned
data instead (a goal per episode, ``desired_goal`` in the observation, radius 0.45, episodes
that never end). :class:`D4RLAntMazeTask` maps D4RL's task onto the Minari maze:

* the maze of the data's env must have D4RL's walls, either as the same rows or with the rows
  in reverse order (Gymnasium-Robotics puts row 0 at the top, ``+y`` downwards; D4RL puts
  row ``i`` at ``y = 4 i``): the ``R``/``G`` cells and the direction of D4RL's goal noise are
  carried over accordingly. Minari's ``umaze`` data map is D4RL's upside down (the same
  world layout); ``umaze-diverse``'s (the registered ``U_MAZE``: walls that read the same
  both ways, no ``G`` cell) is taken the same way, so the task sits where D4RL's does; its
  ``medium``/``large`` maps keep D4RL's rows, a mirror image of D4RL's world, which the
  mirror-symmetric Ant cannot tell apart;
* the goal is D4RL's ``G`` cell centre plus the mean of its goal noise, ``+0.75`` along
  D4RL's ``+x`` and ``+y`` (``_rowcol_to_xy`` adds ``U(0, 0.25 s)``, ``goal_sampler`` another
  ``U(0, 0.5) * 0.25 s``, cell size ``s = 4``): D4RL's ``-v2`` envs redraw the goal in that
  ``1.5 x 1.5`` square at each reset, :class:`SingleGoalAntMaze` keeps its centre (or draws
  it as D4RL does with ``goal_noise=True``);
* the start is the ``R`` cell's centre plus D4RL's joint noise (``reset_model``:
  ``U(-0.1, 0.1)`` on every ``qpos``, ``0.1 N(0, 1)`` on every ``qvel``; Gymnasium-Robotics'
  Ant resets without noise).

Facts and their sources are collected in ``docs/reproducing.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

D4RL_SUCCESS_RADIUS = 0.5
"""D4RL AntMaze's sparse reward: 1 within 0.5 of the goal (Gymnasium-Robotics: 0.45)."""
D4RL_RESET_NOISE = 0.1
"""D4RL's Ant ``reset_model``: ``qpos + U(-0.1, 0.1)``, ``qvel + 0.1 N(0, 1)``."""
D4RL_GOAL_NOISE = (0.25, 0.125)
"""D4RL's two one-sided uniform goal offsets, in cell sizes: ``U(0, 0.25 s) + U(0, 0.125 s)``."""

_R, _G = "r", "g"
D4RL_ANTMAZE_MAPS: dict[str, list[list[int | str]]] = {
    "umaze": [
        [1, 1, 1, 1, 1],
        [1, _R, 0, 0, 1],
        [1, 1, 1, 0, 1],
        [1, _G, 0, 0, 1],
        [1, 1, 1, 1, 1],
    ],
    "medium": [
        [1, 1, 1, 1, 1, 1, 1, 1],
        [1, _R, 0, 1, 1, 0, 0, 1],
        [1, 0, 0, 1, 0, 0, 0, 1],
        [1, 1, 0, 0, 0, 1, 1, 1],
        [1, 0, 0, 1, 0, 0, 0, 1],
        [1, 0, 1, 0, 0, 1, 0, 1],
        [1, 0, 0, 0, 1, 0, _G, 1],
        [1, 1, 1, 1, 1, 1, 1, 1],
    ],
    "large": [
        [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1],
        [1, _R, 0, 0, 0, 1, 0, 0, 0, 0, 0, 1],
        [1, 0, 1, 1, 0, 1, 0, 1, 0, 1, 0, 1],
        [1, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 1],
        [1, 0, 1, 1, 1, 1, 0, 1, 1, 1, 0, 1],
        [1, 0, 0, 1, 0, 1, 0, 0, 0, 0, 0, 1],
        [1, 1, 0, 1, 0, 1, 0, 1, 0, 1, 1, 1],
        [1, 0, 0, 1, 0, 0, 0, 1, 0, _G, 0, 1],
        [1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1],
    ],
}
"""D4RL's evaluation maps (``maze_env.U_MAZE_TEST``, ``BIG_MAZE_TEST``, ``HARDEST_MAZE_TEST``),
row ``i`` at D4RL's ``y = 4 i``."""
D4RL_ANTMAZE_HORIZONS = {"umaze": 700, "medium": 1000, "large": 1000}
"""``max_episode_steps`` of D4RL's ``antmaze-<maze>-*-v2`` registrations."""
D4RL_ANT_STEP_SECONDS = 0.1
"""Simulated seconds per step of D4RL's ant: ``timestep="0.02"`` (``locomotion/assets/ant.xml``)
x frame skip 5 (``locomotion/ant.py``). Gymnasium-Robotics' ant, which Minari's data were
recorded with, steps 0.05 s (timestep 0.01 x 5): D4RL's 700 steps are 70 s, 35 s here."""


def d4rl_horizon_seconds(dataset: str) -> float:
    """D4RL's episode length in simulated seconds for a Minari AntMaze data set name.

    Examples:
        >>> d4rl_horizon_seconds("umaze-diverse"), d4rl_horizon_seconds("large-play")
        (70.0, 100.0)
    """
    return D4RL_ANTMAZE_HORIZONS[d4rl_maze_of(dataset)] * D4RL_ANT_STEP_SECONDS


def d4rl_maze_of(dataset: str) -> str:
    """The D4RL maze of a Minari AntMaze data set name.

    Examples:
        >>> d4rl_maze_of("umaze-diverse"), d4rl_maze_of("large-play")
        ('umaze', 'large')
    """
    maze = dataset.split("-")[0]
    if maze not in D4RL_ANTMAZE_MAPS:
        raise ValueError(
            f"no D4RL AntMaze task for the data set {dataset!r}: D4RL defines "
            f"{sorted(D4RL_ANTMAZE_MAPS)} (use env.protocol=minari for other mazes)"
        )
    return maze


def _walls(maze_map: Sequence[Sequence[Any]]) -> list[list[bool]]:
    return [[cell == 1 for cell in row] for row in maze_map]


def _find(maze_map: Sequence[Sequence[Any]], marker: str) -> tuple[int, int]:
    for i, row in enumerate(maze_map):
        for j, cell in enumerate(row):
            if cell == marker:
                return i, j
    raise ValueError(f"the map has no {marker!r} cell")


@dataclass(frozen=True)
class D4RLAntMazeTask:
    """D4RL's single-goal task in the coordinates of a Gymnasium-Robotics maze.

    Args:
        reset_cell (tuple of int): ``(row, col)`` of D4RL's ``R`` cell in the env's map.
        goal_cell (tuple of int): ``(row, col)`` of D4RL's ``G`` cell in the env's map.
        goal (np.ndarray): the task goal ``(x, y)`` in the env's world coordinates.
        goal_noise_axes (np.ndarray): ``2 x 2``, D4RL's ``+x`` and ``+y`` as world vectors
            (the goal noise of ``goal_noise=True`` is drawn along them).
        maze_size_scaling (float): the cell size.
        max_episode_steps (int): D4RL's time limit of this maze.

    Examples:
        >>> from gymnasium_robotics.envs.maze.maps import U_MAZE
        >>> flipped = [[1] * 5, [1, "g", 0, 0, 1], [1, 1, 1, 0, 1], [1, "r", 0, 0, 1], [1] * 5]
        >>> task = D4RLAntMazeTask.for_maze("umaze", flipped, maze_size_scaling=4.0)
        >>> task.reset_cell, task.goal_cell, task.goal.tolist()
        ((3, 1), (1, 1), [-3.25, 4.75])
    """

    reset_cell: tuple[int, int]
    goal_cell: tuple[int, int]
    goal: np.ndarray
    goal_noise_axes: np.ndarray
    maze_size_scaling: float
    max_episode_steps: int

    @classmethod
    def for_maze(
        cls, maze: str, env_map: Sequence[Sequence[Any]], *, maze_size_scaling: float
    ) -> D4RLAntMazeTask:
        """D4RL's ``maze`` task placed in the Gymnasium-Robotics map ``env_map``.

        Raises:
            ValueError: the env's walls are neither D4RL's nor D4RL's upside down.
        """
        d4rl_map = D4RL_ANTMAZE_MAPS[maze]
        rows = len(d4rl_map)
        same, flipped = (
            _walls(env_map) == _walls(d4rl_map),
            _walls(env_map) == _walls(d4rl_map[::-1]),
        )
        if not (same or flipped):
            raise ValueError(
                f"the data set's maze is not D4RL's antmaze-{maze} (nor it upside down); "
                "its task cannot be placed there: use env.protocol=minari"
            )
        if same and flipped:  # walls symmetric in the rows (U-maze): the env's G cell decides,
            try:  # else D4RL's layout upside down, as Minari's umaze data map
                goal_row, goal_col = _find(d4rl_map, _G)
                flipped = _find(env_map, _G) != (goal_row, goal_col)
            except ValueError:
                flipped = True
        d4rl_reset, d4rl_goal = _find(d4rl_map, _R), _find(d4rl_map, _G)

        def to_env(cell: tuple[int, int]) -> tuple[int, int]:
            return (rows - 1 - cell[0], cell[1]) if flipped else cell

        scale = float(maze_size_scaling)
        width = len(env_map[0]) * scale
        height = rows * scale

        def centre(cell: tuple[int, int]) -> np.ndarray:  # Gymnasium-Robotics' cell_rowcol_to_xy
            return np.array(
                [(cell[1] + 0.5) * scale - width / 2, height / 2 - (cell[0] + 0.5) * scale]
            )

        # D4RL's +y is its +row; Gymnasium-Robotics draws rows downwards (-y), so D4RL's +y
        # is the world's +y when the env's rows are D4RL's upside down, and -y otherwise.
        axes = np.array([[1.0, 0.0], [0.0, 1.0 if flipped else -1.0]])
        mean_offset = scale * (D4RL_GOAL_NOISE[0] + D4RL_GOAL_NOISE[1]) / 2
        goal_cell = to_env(d4rl_goal)
        return cls(
            reset_cell=to_env(d4rl_reset),
            goal_cell=goal_cell,
            goal=centre(goal_cell) + mean_offset * axes.sum(0),
            goal_noise_axes=axes,
            maze_size_scaling=scale,
            max_episode_steps=D4RL_ANTMAZE_HORIZONS[maze],
        )

    def sample_goal(self, rng: np.random.Generator) -> np.ndarray:
        """A goal drawn as D4RL's ``-v2`` envs draw one at each reset."""
        mean = sum(D4RL_GOAL_NOISE) / 2
        offset = rng.uniform(0, D4RL_GOAL_NOISE[0], 2) + rng.uniform(0, D4RL_GOAL_NOISE[1], 2)
        return self.goal + self.maze_size_scaling * (offset - mean) @ self.goal_noise_axes


class SingleGoalAntMaze(gym.Wrapper):
    """A Gymnasium-Robotics AntMaze env playing D4RL's single-goal task.

    Each reset puts the ant at the task's reset cell (centre, plus D4RL's joint noise)
    and the goal at :attr:`D4RLAntMazeTask.goal`; each step's reward is 1 within
    0.5 of it and 0 elsewhere, and the episode terminates at the first success
    (``info["success"]``). The observation dict is passed on; its ``desired_goal`` is the
    task goal (the recipe leaves it out of the policy's input). ``reset``'s ``options``
    (Gymnasium-Robotics' ``goal_cell`` / ``reset_cell``) are not used: the task fixes both.

    Args:
        env (gym.Env): a Gymnasium-Robotics ``AntMaze_*`` env (any wrapper of it).
        task (D4RLAntMazeTask): the task in that env's coordinates.

    Keyword Args:
        goal_noise (bool): draw the goal at each reset as D4RL's ``-v2`` envs do instead of
            its centre. Defaults to ``False``.
        reset_noise (float): D4RL's joint noise at reset, ``U(-n, n)`` on every ``qpos``
            and ``n N(0, 1)`` on every ``qvel`` (Gymnasium-Robotics' Ant has none).
            Defaults to 0.1 (D4RL's).

    Examples:
        >>> import gymnasium as gym
        >>> from torchrl_dual.envs import register_robotics_envs, release_maze_xml
        >>> _ = register_robotics_envs()
        >>> flipped = [[1] * 5, [1, "g", 0, 0, 1], [1, 1, 1, 0, 1], [1, "r", 0, 0, 1], [1] * 5]
        >>> raw = release_maze_xml(gym.make("AntMaze_UMaze-v5", maze_map=flipped))
        >>> task = D4RLAntMazeTask.for_maze("umaze", flipped, maze_size_scaling=4.0)
        >>> env = SingleGoalAntMaze(raw, task)
        >>> obs, info = env.reset(seed=0)
        >>> bool(abs(obs["achieved_goal"] - [-4.0, -4.0]).max() <= 0.1), obs["desired_goal"].tolist()
        (True, [-3.25, 4.75])
        >>> _, reward, terminated, _, info = env.step(env.action_space.sample())
        >>> reward, terminated, info["success"]
        (0.0, False, False)
    """

    def __init__(
        self,
        env: gym.Env,
        task: D4RLAntMazeTask,
        *,
        goal_noise: bool = False,
        reset_noise: float = D4RL_RESET_NOISE,
    ) -> None:
        super().__init__(env)
        maze_env = env.unwrapped
        for name in ("maze", "update_target_site_pos", "position_noise_range"):
            if not hasattr(maze_env, name):
                raise TypeError(
                    f"SingleGoalAntMaze needs a Gymnasium-Robotics maze env, got "
                    f"{type(maze_env).__name__} (no {name!r})"
                )
        maze_env.reset_target = False  # the goal never moves inside an episode
        self.task = task
        self.goal_noise = goal_noise
        self.reset_noise = reset_noise
        self._goal = task.goal.copy()

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Resets the Ant to the task's reset cell with D4RL's joint noise and sets the goal.

        Args:
            seed (int, optional): the env's seed.
            options (dict, optional): ignored; the task fixes the reset and goal cells.

        Returns:
            ``(observation, info)``; the observation's ``desired_goal`` is the task's goal (drawn
            around it with ``goal_noise``) and ``info["success"]`` says whether the Ant is already
            there.
        """
        maze_env = self.env.unwrapped
        noise = maze_env.position_noise_range
        maze_env.position_noise_range = 0.0  # the cells' centres; the Ant adds its joint noise
        cells = {
            "reset_cell": np.array(self.task.reset_cell),
            "goal_cell": np.array(self.task.goal_cell),
        }
        try:
            obs, info = self.env.reset(seed=seed, options=cells)
        finally:
            maze_env.position_noise_range = noise
        self._goal = (
            self.task.sample_goal(maze_env.np_random) if self.goal_noise else self.task.goal.copy()
        )
        maze_env.goal = self._goal.copy()
        maze_env.update_target_site_pos()
        ant = maze_env.ant_env  # Gymnasium-Robotics' Ant resets without noise: D4RL's here
        rng = maze_env.np_random
        qpos = ant.data.qpos + rng.uniform(-self.reset_noise, self.reset_noise, ant.model.nq)
        qvel = ant.data.qvel + self.reset_noise * rng.standard_normal(ant.model.nv)
        ant.set_state(qpos, qvel)
        obs = {**maze_env._get_obs(ant._get_obs()), "desired_goal": self._goal.copy()}
        return obs, {**info, "success": self._success(obs)}

    def _success(self, obs: dict[str, np.ndarray]) -> bool:
        return bool(np.linalg.norm(obs["achieved_goal"] - self._goal) <= D4RL_SUCCESS_RADIUS)

    def step(self, action: Any):
        """Steps the env with D4RL's sparse reward: 1 and termination on reaching the goal.

        Args:
            action: the Ant's action.

        Returns:
            ``(observation, reward, terminated, truncated, info)``, ``reward`` ``float(success)``,
            ``terminated`` ``success`` and ``info["success"]`` set.
        """
        obs, _, _, truncated, info = self.env.step(action)
        obs = {**obs, "desired_goal": self._goal.copy()}
        success = self._success(obs)
        info = {**info, "success": success}
        return obs, float(success), success, truncated, info
