"""PointMaze data that leave cells unvisited (``avoid_cells``, issue 29): a task the
online phase has to explore, the goal in a region the offline data never reach."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium_robotics.envs.maze.maps import MEDIUM_MAZE, U_MAZE

from torchrl_dual.data.maze_controller import MazeWaypointController
from torchrl_dual.data.maze_dataset import generate_maze_dataset, load_or_generate_maze_dataset


def _cells(data, ctrl: MazeWaypointController) -> set[tuple[int, int]]:
    xy = data.transitions["observation"][:, :2].numpy()
    rows = np.floor((ctrl.y_center - xy[:, 1]) / ctrl.scaling).astype(int)
    cols = np.floor((xy[:, 0] + ctrl.x_center) / ctrl.scaling).astype(int)
    return set(zip(rows.tolist(), cols.tolist(), strict=True))


def test_the_controller_plans_around_avoided_cells_and_steers_out_of_them():
    ctrl = MazeWaypointController(U_MAZE, action_noise=0.0, avoid_cells=[[3, 1]])
    assert (3, 1) not in ctrl.free_cells and ctrl.num_free_cells == 6
    inside = ctrl.cell_to_xy((3, 1))
    assert ctrl.xy_to_cell(inside) == (3, 2)  # counted as its nearest allowed cell
    action = ctrl.act(inside, np.zeros(2), ctrl.cell_to_xy((1, 1)))
    assert action[0] > 0  # heads right, out of the avoided dead end
    with pytest.raises(ValueError, match="is a wall"):
        MazeWaypointController(U_MAZE, avoid_cells=[[0, 0]])
    with pytest.raises(ValueError, match="outside"):
        MazeWaypointController(U_MAZE, avoid_cells=[[9, 9]])


def test_data_with_the_goal_in_an_avoided_region_hold_no_reward():
    """Medium's bottom-right room (4 cells) avoided, the goal in it: the data never reach
    it; the references stay the unconstrained controller's, which does."""
    room = [[5, 6], [6, 5], [6, 6], [4, 6]]
    data = generate_maze_dataset(
        "medium", 4000, seed=0, goal_cell=[6, 6], avoid_cells=room, num_reference_episodes=2
    )
    ctrl = MazeWaypointController(MEDIUM_MAZE)
    visited = _cells(data, ctrl)
    assert not visited & {tuple(cell) for cell in room}
    assert data.metadata["avoided_fraction"] == 0.0
    assert data.metadata["reward_fraction"] == 0.0
    assert data.metadata["avoid_cells"] == sorted(room)
    assert data.reference_max > data.reference_min  # the references reach the goal
    plain = generate_maze_dataset(
        "medium", 4000, seed=0, goal_cell=[6, 6], num_reference_episodes=0
    )
    assert _cells(plain, ctrl) & {tuple(cell) for cell in room}  # without: visited


def test_avoided_data_are_cached_apart_from_the_full_data(tmp_path):
    kw = dict(num_reference_episodes=0, verbose=False, max_episode_steps=100)
    full = load_or_generate_maze_dataset("umaze", 300, 0, tmp_path, **kw)
    avoided = load_or_generate_maze_dataset("umaze", 300, 0, tmp_path, avoid_cells=[[3, 1]], **kw)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["pointmaze-umaze-avoid3_1-n300-seed0", "pointmaze-umaze-n300-seed0"]
    assert full.metadata["avoid_cells"] == [] and avoided.metadata["avoid_cells"] == [[3, 1]]
