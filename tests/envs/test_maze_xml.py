"""The temp model file Gymnasium-Robotics writes for each maze env is deleted once the env
is built (``torchrl_dual/envs/maze_xml.py``), and the env still runs."""

from __future__ import annotations

import os
import tempfile

import pytest

from torchrl_dual.envs import make_pointmaze_env, make_pointmaze_gym_env, release_maze_xml


@pytest.mark.parametrize("shift", ["none", "rotation"])
def test_torchrl_pointmaze_envs_leave_no_model_file_and_still_step(shift):
    env = make_pointmaze_env("umaze", max_episode_steps=4, shift=shift)
    path = env.base_env._env.unwrapped.tmp_xml_file_path
    assert os.path.dirname(path) == tempfile.gettempdir()  # where the upstream writes it
    assert not os.path.exists(path)
    assert env.rollout(4)["next", "observation"].shape[0] == 4  # the model was loaded


def test_gym_pointmaze_env_leaves_no_model_file():
    env = make_pointmaze_gym_env("umaze", max_episode_steps=3)
    assert not os.path.exists(env.unwrapped.tmp_xml_file_path)
    env.reset(seed=0)
    env.step(env.action_space.sample())


def test_only_the_maze_temp_file_is_deleted(tmp_path):
    """An env whose ``tmp_xml_file_path`` is not the upstream's temp file keeps it."""

    class Env:
        unwrapped = None

    elsewhere = tmp_path / "ant_maze1.xml"  # right name, wrong directory
    elsewhere.write_text("<mujoco/>")
    env = Env()
    env.unwrapped = type("Raw", (), {"tmp_xml_file_path": str(elsewhere)})()
    assert release_maze_xml(env) is env and elsewhere.exists()
    mine = tempfile.NamedTemporaryFile(suffix=".xml", prefix="model", delete=False)
    env.unwrapped.tmp_xml_file_path = mine.name  # right directory, another file's name
    release_maze_xml(env)
    assert os.path.exists(mine.name)
    os.remove(mine.name)
    assert release_maze_xml(object()) is not None  # not a maze env: untouched
