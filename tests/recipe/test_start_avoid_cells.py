"""``env.start_avoid_cells`` (issue 41): no online, collector-worker or evaluation episode
of PointMaze starts in the given cells; a wall, an outside cell or no cell left is one
``error:`` line; at ``null`` (the default) every start is the one of before, bit for bit,
and the offline phase's cache key does not change."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from omegaconf import OmegaConf
from tensordict.nn import TensorDictModule

from torchrl_dual.envs import open_cells, start_cells
from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked
from torchrl_dual.recipe.kits import build as env_kits
from torchrl_dual.recipe.kits import pointmaze as pointmaze_kit
from torchrl_dual.recipe.o2o.offline_cache import offline_key_config

ROOM = [[4, 6], [5, 6], [6, 5], [6, 6]]  # Medium's dead end, medium_explore's avoided cells
MEDIUM_EXPLORE = (
    "env=pointmaze_medium",
    "env.goal_cell=[6,6]",
    f"env.data_avoid_cells={ROOM}".replace(" ", ""),
)
AVOID = "env.start_avoid_cells=${env.data_avoid_cells}"


def compose(tmp_path: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [f"output_dir={tmp_path / 'run'}", "budget=smoke", *overrides],
    )


def cell_of(xy) -> tuple[int, int]:
    """The Medium maze cell (8 x 8, unit cells, centred at the origin) holding ``(x, y)``."""
    return (math.floor(4 - float(xy[1])), math.floor(float(xy[0]) + 4))


def online_starts(cfg, seeds: range) -> list[list[float]]:
    """The ``(x, y)`` where the online env of ``cfg`` (a collector worker's: the picklable
    factory) starts, one reset after seeding with each of ``seeds``."""
    env = env_kits.TrainEnvFactory(cfg)()
    starts = []
    for seed in seeds:
        env.set_seed(seed)
        starts.append(env.reset()["observation"][:2].tolist())
    return starts


def evaluation_starts(cfg) -> list[list[float]]:
    """The ``(x, y)`` of every evaluation episode's start: the evaluator's policy records
    the first batch it is given (``env.max_episode_steps=1``: one batch)."""
    seen = []

    def act(observation: torch.Tensor) -> torch.Tensor:
        seen.append(observation[:, :2].clone())
        return torch.zeros(*observation.shape[:-1], 2)

    policy = TensorDictModule(act, in_keys=["observation"], out_keys=["action"])
    data = SimpleNamespace(normalized_score=lambda ret: ret)
    env_kits.make_evaluator(cfg, data)(policy)
    return seen[0].tolist()


# ----------------------------------------------------------------------------- starts
def test_no_online_or_evaluation_episode_starts_inside_the_avoided_cells(tmp_path):
    steps = ("algo=iql", "env.max_episode_steps=1", "budget.eval_episodes=60")
    before = compose(tmp_path, *MEDIUM_EXPLORE, *steps)
    after = compose(tmp_path, *MEDIUM_EXPLORE, *steps, AVOID)
    assert after.env.start_avoid_cells == ROOM
    room = {tuple(cell) for cell in ROOM}
    allowed = set(start_cells("medium", (6, 6), ROOM))
    for starts in (online_starts, lambda cfg: evaluation_starts(cfg)):
        args = (range(150),) if starts is online_starts else ()
        old = {cell_of(xy) for xy in starts(before, *args)}
        new = {cell_of(xy) for xy in starts(after, *args)}
        assert old & room, "the test must be able to see a start inside the room"
        assert not new & room and new <= allowed
        assert len(new) >= 18  # the starts still spread over the other cells (22)


def test_with_a_random_goal_the_avoided_cells_stay_goals_but_no_start(tmp_path):
    cfg = compose(tmp_path, "env=pointmaze_medium", f"env.start_avoid_cells={ROOM}")
    env = env_kits.TrainEnvFactory(cfg)()
    room = {tuple(cell) for cell in ROOM}
    starts, goals = set(), set()
    for seed in range(150):
        env.set_seed(seed)
        observation = env.reset()["observation"]
        starts.add(cell_of(observation[:2]))
        goals.add(cell_of(observation[4:6]))
    assert not starts & room
    assert goals & room  # the task keeps its goals: only the starts move


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize(
    ("cells", "message"),
    [
        ("[[0,0]]", r"start_avoid_cells entry \[0, 0\] is not an open cell of the medium"),
        ("[[9,9]]", r"start_avoid_cells entry \[9, 9\] is not an open cell of the medium"),
        ("[3,1]", r"must be null or a list of \[row, col\] cells"),
    ],
)
def test_a_wall_or_an_outside_cell_is_a_config_error(tmp_path, cells, message):
    with pytest.raises(ConfigError, match=message) as err:
        compose(tmp_path, "env=pointmaze_medium", f"env.start_avoid_cells={cells}")
    assert str(err.value).startswith("env.start_avoid_cells=")


def test_leaving_no_start_cell_is_a_config_error(tmp_path):
    every = [list(cell) for cell in open_cells("umaze") if cell != (3, 1)]
    fixed = ("env.goal_cell=[3,1]", f"env.start_avoid_cells={every}".replace(" ", ""))
    with pytest.raises(ConfigError, match="leave no open cell of the umaze maze"):
        compose(tmp_path, *fixed)
    one_left = f"env.start_avoid_cells={every[1:]}".replace(" ", "")
    compose(tmp_path, "env.goal_cell=[3,1]", one_left)  # one start cell: enough
    with pytest.raises(ConfigError, match="with a random goal per episode .* at least 2"):
        compose(tmp_path, one_left.replace("]]", "],[3,1]]"))  # random goal, 1 cell left


def test_the_command_line_says_it_in_one_error_line(tmp_path):
    every = [list(cell) for cell in open_cells("umaze") if cell != (3, 1)]
    proc = subprocess.run(
        [
            sys.executable, "recipes/o2o.py", "env.goal_cell=[3,1]",
            f"env.start_avoid_cells={every}".replace(" ", ""), f"hydra.run.dir={tmp_path}",
        ],
        cwd=Path(__file__).resolve().parents[2],
        env={**os.environ, "OMP_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"},
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-3000:]
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("error: env.start_avoid_cells=[[1, 1], ") and "no open cell" in line


# ----------------------------------------------------------------------------- the default
# start (x, y, vx, vy) of 3 resets of the online env seeded 3, and (x, y, goal x, goal y) of
# the evaluator's first 3 episodes at seed 0, recorded before the key existed (commit d4b9788)
ONLINE_BEFORE = {
    "[6,6]": [
        [2.329869508743286, -1.382711410522461],
        [-1.5346859693527222, -2.4566006660461426],
        [-2.6078994274139404, -0.42572638392448425],
    ],
    "null": [
        [0.6172885894775391, 0.30683600902557373],
        [-0.45660072565078735, 0.6189188957214355],
        [1.5981080532073975, -2.603639602661133],
    ],
}
EVALUATION_BEFORE = {
    "[6,6]": [
        [0.35796067569500284, -0.6650463474867481, 2.5083452011652314, -2.5381504237417847],
        [1.431817741151708, -2.598409014843474, 2.6074032115807326, -2.4352648834392014],
        [-0.7459404376527279, 0.5731865840519839, 2.5675929497146748, -2.6249925157720604],
    ],
    "null": [
        [-1.642039324304997, -0.6650463474867481, -2.5381504237417847, 1.5371378386156984],
        [-0.5681822588482921, -1.598409014843474, 0.5647351165607988, 0.41924242570521625],
        [2.254059562347272, -0.4268134159480162, 1.3750074842279398, -2.4752898792003584],
    ],
}


@pytest.mark.parametrize("goal", ["[6,6]", "null"])
def test_the_default_starts_every_episode_where_it_started_before(tmp_path, goal):
    cfg = compose(tmp_path, "env=pointmaze_medium", f"env.goal_cell={goal}", "seed=3")
    assert cfg.env.start_avoid_cells is None
    env = env_kits.make_train_env(cfg)
    online = [env.reset()["observation"][:2].tolist() for _ in range(3)]
    assert online == ONLINE_BEFORE[goal]  # float32 values, compared exactly
    evaluation = pointmaze_kit.make_pointmaze_gym_env(
        "medium", goal_cell=None if goal == "null" else [6, 6]
    )
    for i, expected in enumerate(EVALUATION_BEFORE[goal]):
        obs = evaluation.reset(seed=10_000 + i)[0]
        assert [*obs["observation"][:2], *obs["desired_goal"]] == expected


def test_the_key_keeps_the_offline_phase_and_its_cache_key(tmp_path):
    """An online key: with and without it the offline phase is the same, and a config of
    before the key (without it) has the key of today's default."""
    base = compose(tmp_path, *MEDIUM_EXPLORE)
    avoiding = compose(tmp_path, *MEDIUM_EXPLORE, AVOID)
    base, avoiding = (OmegaConf.to_container(c, resolve=True) for c in (base, avoiding))
    assert offline_key_config(base) == offline_key_config(avoiding)
    before = offline_key_config(base)
    del base["env"]["start_avoid_cells"]
    assert offline_key_config(base) == before


# ----------------------------------------------------------------------------- the reading
def test_medium_explore_starts_one_to_two_moves_from_the_goal_in_12_percent_of_episodes():
    """The reading of benchmarks/notebook.md ("Where medium_explore's episodes start")."""
    env = OmegaConf.create(
        {"maze": "medium", "goal_cell": [6, 6], "data_avoid_cells": ROOM, "start_avoid_cells": None}
    )
    before = pointmaze_kit.pointmaze_start_distances(env)
    assert sum(before["goal"].values()) == 25 and before["avoided"][0] == 3  # 12 %
    assert (before["goal"][1], before["goal"][2]) == (2, 1)
    env.start_avoid_cells = ROOM
    after = pointmaze_kit.pointmaze_start_distances(env)
    assert sum(after["goal"].values()) == 22 and min(after["goal"]) == 3
    assert min(after["avoided"]) == 1
    # the cells left out are exactly the three inside the room
    assert {d: before["goal"][d] - after["goal"].get(d, 0) for d in before["goal"]} == {
        1: 2, 2: 1, **{d: 0 for d in range(3, 11)}
    }  # fmt: skip
