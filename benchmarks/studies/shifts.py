"""How much do the online dynamics shifts (``env.shift=``) hurt a competent offline policy?

PointMaze: the data set's own waypoint controller
(:class:`~torchrl_dual.data.MazeWaypointController`) drives the env without a shift and
under each shift, on the same resets (seeds); ``expert`` is the noise-free controller,
``behaviour`` the noisy one (``action_noise=0.5``) whose return is the normalized-score
reference (100). A shift "matters" when the controller keeps at most half of its score.

Frozen-Lake: exact success probabilities (value iteration) of the policy optimal for the
offline data's dynamics, without the shift and under ``biased_slip``, next to the policy
optimal under the shift, and how many cells the optimal action changes in.

Run (about 70 s on one core; the table in ``docs/recipe.md``)::

    OMP_NUM_THREADS=1 python -m benchmarks.studies.shifts --episodes 50
"""

from __future__ import annotations

import argparse
import shlex
import sys
import time
from datetime import datetime, timezone

import numpy as np

from torchrl_dual.data import MazeWaypointController
from torchrl_dual.envs import (
    frozenlake_optimal_policy,
    frozenlake_success_probability,
    make_pointmaze_gym_env,
)


def controller_returns(
    maze: str,
    episodes: int,
    action_noise: float,
    *,
    shift: str = "none",
    angle: float | None = None,
    scale: float | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Returns of the waypoint controller chasing the task goal, one per episode."""
    env = make_pointmaze_gym_env(maze, shift=shift, shift_angle=angle, shift_scale=scale)
    inner = env.unwrapped.maze
    returns = np.zeros(episodes)
    for ep in range(episodes):
        rng = np.random.default_rng([seed, ep])
        ctrl = MazeWaypointController(
            inner.maze_map,
            maze_size_scaling=inner.maze_size_scaling,
            action_noise=action_noise,
            rng=rng,
        )
        obs, _ = env.reset(seed=seed * 100_003 + ep)
        done = False
        while not done:
            state = obs["observation"]
            action = ctrl.act(state[:2], state[2:4], obs["desired_goal"])
            obs, reward, terminated, truncated, _ = env.step(action)
            returns[ep] += float(reward)
            done = terminated or truncated
    env.close()
    return returns


def random_returns(maze: str, episodes: int, seed: int = 0) -> np.ndarray:
    env = make_pointmaze_gym_env(maze)
    returns = np.zeros(episodes)
    for ep in range(episodes):
        rng = np.random.default_rng([seed, ep, 1])
        env.reset(seed=seed * 100_003 + ep)
        done = False
        while not done:
            _, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2))
            returns[ep] += float(reward)
            done = terminated or truncated
    env.close()
    return returns


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--maze", default="umaze")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--shifts",
        default=(
            "rotation:45,rotation:60,rotation:75,rotation:90,damping:50,damping:100,"
            "damping:150,mass:0.3,mass:3,mass:10,mass:20"
        ),
        help="comma-separated name:value (angle in degrees for rotation, else the scale)",
    )
    parser.add_argument("--frozenlake-map", default="8x8")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    print(
        f"$ OMP_NUM_THREADS=1 python {shlex.join(['-m', 'benchmarks.studies.shifts', *sys.argv[1:]])}"
    )
    print(f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC, {args.episodes} episodes, same seeds")
    print()

    cases: list[tuple[str, str, float | None]] = [("none", "none", None)]
    for item in args.shifts.split(","):
        name, _, value = item.partition(":")
        cases.append((item, name, float(value) if value else None))
    random_mean = float(random_returns(args.maze, args.episodes, args.seed).mean())
    results: dict = {"pointmaze": {}, "frozenlake": {}}
    rows = []
    for label, name, value in cases:
        kw = {"angle": value} if name == "rotation" else {"scale": value}
        row = {}
        for policy, noise in (("expert", 0.0), ("behaviour", 0.5)):
            rets = controller_returns(
                args.maze, args.episodes, noise, shift=name, seed=args.seed, **kw
            )
            row[policy] = float(rets.mean())
        rows.append((label, row))
        results["pointmaze"][label] = row
    ref = results["pointmaze"]["none"]["behaviour"]

    def score(ret: float) -> float:
        return 100 * (ret - random_mean) / (ref - random_mean)

    print(f"PointMaze {args.maze}: return (normalized score; random = {random_mean:.1f},")
    print("behaviour controller without shift = 100), and the fraction of the unshifted score kept")
    print()
    print("| shift | expert return | expert kept | behaviour return | behaviour score | kept |")
    print("|---|---|---|---|---|---|")
    base = results["pointmaze"]["none"]
    for label, row in rows:
        print(
            f"| {label} | {row['expert']:.1f} | {row['expert'] / base['expert']:.2f} | "
            f"{row['behaviour']:.1f} | {score(row['behaviour']):.1f} | "
            f"{row['behaviour'] / base['behaviour']:.2f} |"
        )
    print()

    fl = args.frozenlake_map
    offline_pi = frozenlake_optimal_policy(fl, 3 / 4)
    fl_shifts = ("none", "biased_slip", "biased_slip_cw")
    table = {"offline-optimal (data: 3/4, symmetric slip)": offline_pi}
    for shift in fl_shifts:
        table[f"optimal online under {shift} (2/3)"] = frozenlake_optimal_policy(
            fl, 2 / 3, shift=shift
        )
    print(f"Frozen-Lake {fl}: exact success probability within 100 steps, online success")
    print("rate 2/3; last column: cells where the policy's action differs from the offline-optimal")
    print()
    print("| policy | " + " | ".join(f"online, {s}" for s in fl_shifts) + " | cells changed |")
    print("|---|" + "---|" * (len(fl_shifts) + 1))
    for label, pi in table.items():
        row = {s: float(frozenlake_success_probability(pi, fl, 2 / 3, shift=s)) for s in fl_shifts}
        row["cells_changed"] = int((pi != offline_pi).sum())
        results["frozenlake"][label] = row
        cells = " | ".join(f"{row[s]:.4f}" for s in fl_shifts)
        print(f"| {label} | {cells} | {row['cells_changed']} |")
    print(f"\n{time.perf_counter() - start:.0f} s")
    return results


if __name__ == "__main__":
    main()
