"""What training a goal-reaching Ant controller (for local AntMaze data) would cost here.

    python -m benchmarks.speed.ant_controller_cost                 # ~1 minute
    python -m benchmarks.speed.ant_controller_cost --updates 200 --steps 2000

D4RL-style AntMaze data is a goal-reaching Ant policy driven along maze waypoints. The
Minari generation scripts train that policy with SAC (``scripts/antmaze/train_ant.py`` of
Farama-Foundation/minari-dataset-generation-scripts: 30M env steps over 16 envs,
one gradient step of batch 256 per vectorized step, so 30M / 16 = 1.875M updates, MLPs of
4 x 256). This script times, on this machine and one thread, the two parts of that
training with TorchRL's own pieces: a :class:`~torchrl.objectives.SACLoss` update of that
size (actor + twin Q, Adam, soft target update) and an Ant env step (``Ant-v5``, the body
AntMaze uses) with a policy forward, then projects the script's budget and smaller ones.
Issue #10 ships a local AntMaze data set only if the controller trains in <= 2 hours.
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate

OBS_DIM = 27 + 2  # Ant observation + waypoint direction (the goal-reaching input)
ACT_DIM = 8
MINARI_ENV_STEPS = 30_000_000
MINARI_UPDATES = MINARI_ENV_STEPS // 16


def sac_loss(width: int, depth: int) -> tuple[SACLoss, torch.optim.Optimizer, SoftUpdate]:
    spec = Bounded(-1.0, 1.0, (ACT_DIM,))
    actor_net = nn.Sequential(
        MLP(OBS_DIM, 2 * ACT_DIM, num_cells=[width] * depth), NormalParamExtractor()
    )
    actor = ProbabilisticActor(
        TensorDictModule(actor_net, ["observation"], ["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
    )
    qvalue = ValueOperator(
        MLP(OBS_DIM + ACT_DIM, 1, num_cells=[width] * depth), in_keys=["observation", "action"]
    )
    loss = SACLoss(actor, qvalue, num_qvalue_nets=2, action_spec=spec)
    loss.make_value_estimator(gamma=0.991)
    return loss, torch.optim.Adam(loss.parameters(), lr=3e-4), SoftUpdate(loss, tau=0.03)


def batch(size: int, obs_dim: int = OBS_DIM, act_dim: int = ACT_DIM) -> TensorDict:
    """``size`` random non-terminal transitions (also used by ``so2_cost.py``)."""
    return TensorDict(
        {
            "observation": torch.randn(size, obs_dim),
            "action": torch.rand(size, act_dim) * 2 - 1,
            ("next", "observation"): torch.randn(size, obs_dim),
            ("next", "reward"): torch.randn(size, 1),
            ("next", "done"): torch.zeros(size, 1, dtype=torch.bool),
            ("next", "terminated"): torch.zeros(size, 1, dtype=torch.bool),
        },
        batch_size=[size],
    )


def time_updates(updates: int, width: int, depth: int, batch_size: int) -> float:
    loss, optim, target = sac_loss(width, depth)
    data = batch(batch_size)

    def update() -> None:
        losses = loss(data)
        total = losses["loss_actor"] + losses["loss_qvalue"] + losses["loss_alpha"]
        optim.zero_grad()
        total.backward()
        optim.step()
        target.step()

    for _ in range(5):
        update()
    start = time.process_time()
    for _ in range(updates):
        update()
    return 1000.0 * (time.process_time() - start) / updates


def time_env_steps(steps: int, width: int, depth: int) -> float:
    env = gym.make("Ant-v5")
    env.reset(seed=0)
    policy = MLP(OBS_DIM, 2 * ACT_DIM, num_cells=[width] * depth)
    goal = torch.zeros(2)
    start = time.process_time()
    obs = None
    for _ in range(steps):
        with torch.no_grad():
            x = torch.as_tensor(obs if obs is not None else env.observation_space.sample())
            action = policy(torch.cat([x.float()[:27], goal])).tanh()[:ACT_DIM].numpy()
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset()
    return 1000.0 * (time.process_time() - start) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--updates", type=int, default=100)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--depth", type=int, default=4)
    parser.add_argument("--batch-size", type=int, default=256)
    args = parser.parse_args()
    torch.set_num_threads(1)
    update_ms = time_updates(args.updates, args.width, args.depth, args.batch_size)
    step_ms = time_env_steps(args.steps, args.width, args.depth)
    print(f"SAC update ({args.depth} x {args.width}, batch {args.batch_size}): {update_ms:.1f} ms")
    print(f"Ant-v5 step + policy forward: {step_ms:.3f} ms  (CPU time, one thread)\n")
    print("| budget | env steps | updates | projected CPU hours (1 core) | on 2 cores, ideal |")
    print("|---|---:|---:|---:|---:|")
    for label, fraction in (("Minari's train_ant.py", 1.0), ("1/10 of it", 0.1), ("1/30", 1 / 30)):
        env_steps, updates = MINARI_ENV_STEPS * fraction, MINARI_UPDATES * fraction
        hours = (env_steps * step_ms + updates * update_ms) / 3.6e6
        print(f"| {label} | {env_steps:,.0f} | {updates:,.0f} | {hours:.1f} | {hours / 2:.1f} |")


if __name__ == "__main__":
    main()
