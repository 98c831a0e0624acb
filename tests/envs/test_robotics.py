"""``register_robotics_envs``: Gymnasium-Robotics without its Adroit notice on stderr."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

CHILD = "from torchrl_dual.envs import register_robotics_envs; register_robotics_envs()"


def test_the_adroit_notice_is_dropped_and_everything_else_the_import_prints_is_kept(tmp_path):
    """A stand-in ``gymnasium_robotics`` that prints the notice and another line on import."""
    fake = tmp_path / "gymnasium_robotics"
    fake.mkdir()
    (fake / "__init__.py").write_text(
        textwrap.dedent(
            """
            import sys
            print("AdroitHandDoorDense-v1 environment's reward functions were updated in "
                  "v1.2.1 without an environment version update.", file=sys.stderr)
            print("a warning the user must see", file=sys.stderr)
            """
        )
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    proc = subprocess.run(
        [sys.executable, "-c", CHILD], env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert "reward functions were updated" not in proc.stderr
    assert "a warning the user must see" in proc.stderr


def test_the_real_package_registers_the_mazes_quietly():
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            CHILD + "; import gymnasium as g; print('PointMaze_UMaze-v3' in g.registry)",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "True"
    assert "AdroitHand" not in proc.stderr


def test_pen_drop_termination_refuses_an_env_that_is_not_the_pen():
    import gymnasium as gym
    import pytest

    from torchrl_dual.envs import PenDropTermination

    with pytest.raises(TypeError, match="needs Gymnasium-Robotics' AdroitHandPen, got"):
        PenDropTermination(gym.make("Pendulum-v1"))
