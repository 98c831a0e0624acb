"""Tiny Minari data sets made here, under the published ids, env versions and metadata
fields (the published ones cannot be downloaded where the tests run).

* ``D4RL/antmaze/umaze-v1``: ``AntMaze_UMaze-v4`` with D4RL's U-maze map (goal top left,
  reset bottom left), ``continuing_task=True``, ``reset_target=False``, and the evaluation
  env of the Minari generation scripts (start and goal on the right-hand column);
  ``ref_min_score`` / ``ref_max_score`` present, as in the D4RL imports.
* ``mujoco/hopper/medium-v0``: ``Hopper-v5``; no reference scores (Minari's MuJoCo data
  sets are not D4RL imports).
* ``D4RL/pen/cloned-v2``: ``AdroitHandPen-v1`` with references.

Actions are uniform random and episodes are cut short; the reference values are stand-ins
of the right kind (random < expert), not the published numbers.
"""

from __future__ import annotations

from copy import deepcopy

import gymnasium as gym

from torchrl_dual.data import collect_episodes, write_minari_dataset

R, G = "r", "g"
UMAZE_MAP = [[1, 1, 1, 1, 1], [1, G, 0, 0, 1], [1, 1, 1, 0, 1], [1, R, 0, 0, 1], [1, 1, 1, 1, 1]]
UMAZE_EVAL_MAP = [
    [1, 1, 1, 1, 1],
    [1, 0, 0, R, 1],
    [1, 0, 1, 1, 1],
    [1, 0, 0, G, 1],
    [1, 1, 1, 1, 1],
]

ANTMAZE_ID = "D4RL/antmaze/umaze-v1"
HOPPER_ID = "mujoco/hopper/medium-v0"
PEN_ID = "D4RL/pen/cloned-v2"


def _register() -> None:
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)


def write_antmaze_umaze(num_episodes: int = 4, steps: int = 40):
    _register()
    env = gym.make("AntMaze_UMaze-v4", maze_map=UMAZE_MAP, continuing_task=True, reset_target=False)
    eval_spec = deepcopy(env.spec)
    eval_spec.kwargs["maze_map"] = UMAZE_EVAL_MAP
    buffers = collect_episodes(env, None, num_episodes, max_steps=steps)
    env.close()
    return write_minari_dataset(
        ANTMAZE_ID, buffers, env.spec, eval_env_spec=eval_spec, reference_returns=(0.0, 400.0)
    )


def write_hopper_medium(num_episodes: int = 6, steps: int = 60):
    env = gym.make("Hopper-v5")
    buffers = collect_episodes(env, None, num_episodes, max_steps=steps)
    env.close()
    return write_minari_dataset(HOPPER_ID, buffers, env.spec)


def write_pen_cloned(num_episodes: int = 3, steps: int = 40):
    _register()
    env = gym.make("AdroitHandPen-v1")
    buffers = collect_episodes(env, None, num_episodes, max_steps=steps)
    env.close()
    return write_minari_dataset(PEN_ID, buffers, env.spec, reference_returns=(96.26, 3076.83))
