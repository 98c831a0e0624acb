"""How far does each ODRL locomotion shift (``env.shift=``, level 2.0) move a fixed
open-loop rollout?

For each robot (``Hopper-v5``, ``HalfCheetah-v5``, ``Walker2d-v5``) and shift, the env
without the shift and the shifted env start from the same reset (seed 0) and execute the
same open-loop actions for ``--steps`` steps: zeros, and a sine ``a_{t,i} = sin(2πt/20
+ i)``. Reported: the mean over observation entries of ``|obs_shifted - obs|`` after the
last step, and the difference of the torso's forward position ``x`` (the quantity the
reward integrates). Episode ends (an unhealthy Hopper or Walker2d) are ignored: the
rollout continues, so the numbers compare dynamics, not returns.

Run (a few seconds on one core; the table in ``docs/recipe.md``)::

    OMP_NUM_THREADS=1 python -m benchmarks.studies.locomotion_shifts --steps 100
"""

from __future__ import annotations

import argparse
import shlex
import sys
from datetime import datetime, timezone

import gymnasium as gym
import numpy as np

from torchrl_dual.envs import LOCOMOTION_SHIFTS, apply_shift

ROBOTS = {"hopper": "Hopper-v5", "halfcheetah": "HalfCheetah-v5", "walker2d": "Walker2d-v5"}


def open_loop(
    env_id: str, shift: str, actions: np.ndarray, scale: float
) -> tuple[np.ndarray, float]:
    """The last observation and the torso's x after ``actions``, from reset seed 0."""
    env = apply_shift(gym.make(env_id), shift, scale=scale, kind="locomotion")
    obs, _ = env.reset(seed=0)
    inner = env.unwrapped  # past the time limit and the checker: episode ends are ignored
    for action in actions:
        obs = inner.step(action)[0]
    return obs, float(inner.data.qpos[0])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=100, help="open-loop steps")
    parser.add_argument("--scale", type=float, default=2.0, help="env.shift_scale")
    args = parser.parse_args(argv)
    print(
        f"`python {shlex.join(['-m', 'benchmarks.studies.locomotion_shifts', *sys.argv[1:]])}`, "
        f"{datetime.now(timezone.utc):%Y-%m-%d}\n"
    )
    print("| robot | shift | mean abs Δobs, zero actions | mean abs Δobs, sine | Δx, sine |")
    print("|---|---|---|---|---|")
    for robot, env_id in ROBOTS.items():
        dim = gym.make(env_id).action_space.shape[0]
        t = np.arange(args.steps)[:, None]
        patterns = {
            "zero": np.zeros((args.steps, dim)),
            "sine": np.sin(2 * np.pi * t / 20 + np.arange(dim)),
        }
        plain = {name: open_loop(env_id, "none", a, args.scale) for name, a in patterns.items()}
        for shift in LOCOMOTION_SHIFTS:
            moved = {name: open_loop(env_id, shift, a, args.scale) for name, a in patterns.items()}
            gap = {name: np.abs(moved[name][0] - plain[name][0]).mean() for name in patterns}
            dx = moved["sine"][1] - plain["sine"][1]
            print(f"| {robot} | {shift} | {gap['zero']:.3f} | {gap['sine']:.3f} | {dx:+.3f} |")


if __name__ == "__main__":
    main()
