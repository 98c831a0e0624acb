"""Speed of DUAL's actor+critic update (``DualLearner.update``) at the default networks.

Builds the networks as the recipe does (``recipes/config`` composed with the given
overrides; PointMaze-shaped data: 6-dim observations, 2-dim actions), draws random
batches of ``budget.batch_size`` transitions and times the reference update (the
generic path: TorchRL ``IQLLoss`` losses, the twin target Q looped with ``to_module``,
the actor's window pass) against the current one (``DualLearner.update``), interleaved
in one process, from identical copies of the weights and optimizer states.

    python benchmarks/update_speed.py [--rounds 5] [--updates 50] [--threads 1]
    python benchmarks/update_speed.py --profile   # cProfile top list of each path
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import time
from pathlib import Path
from types import SimpleNamespace

import torch
from tensordict import TensorDict

from torchrl_dual.recipe import networks
from torchrl_dual.recipe.cli import compose_checked
from torchrl_dual.recipe.critics import CRITICS
from torchrl_dual.recipe.dual import DualLearner

OBS_DIM, ACTION_DIM = 6, 2  # PointMaze: (x, y, vx, vy, goal_x, goal_y), force (fx, fy)
CONFIG_DIR = Path(__file__).resolve().parents[1] / "recipes" / "config"


def make_learner(overrides: list[str] | None = None, seed: int = 0) -> DualLearner:
    """A :class:`DualLearner` holding only what ``update`` reads, built by the recipe's
    own builders in the recipe's order."""
    cfg = compose_checked(CONFIG_DIR, list(overrides or []))
    torch.manual_seed(seed)
    obs = torch.randn(4096, OBS_DIM) * 2 + 1
    act = torch.rand(4096, ACTION_DIM) * 2 - 1
    data = SimpleNamespace(
        obs_dim=OBS_DIM,
        action_dim=ACTION_DIM,
        transitions=TensorDict({"observation": obs, "action": act}, [4096]),
    )
    learner = DualLearner.__new__(DualLearner)
    learner.cfg = cfg
    learner.teacher = networks.make_planner(cfg, data)
    learner.actor = networks.make_actor(cfg, learner.teacher)
    # distillation would load trained weights; a random perturbation stands in for it
    with torch.no_grad():
        for p in learner.actor.parameters():
            p.add_(0.05 * torch.randn_like(p))
    learner.critic = CRITICS[cfg.critic.name][1](cfg, OBS_DIM, ACTION_DIM)
    learner.actor_loss = networks.make_actor_loss(cfg, learner.actor, learner.critic)
    learner.actor_optimizer = torch.optim.Adam(learner.actor_loss.parameters(), lr=cfg.actor.lr)
    learner.updates_since_refit = 0
    return learner


def random_batch(batch_size: int, generator: torch.Generator | None = None) -> TensorDict:
    """``batch_size`` PointMaze-shaped transitions (the keys the update reads)."""

    def randn(*shape):
        return torch.randn(*shape, generator=generator)

    done = torch.rand(batch_size, 1, generator=generator) < 0.01
    return TensorDict(
        {
            "observation": randn(batch_size, OBS_DIM),
            "action": torch.rand(batch_size, ACTION_DIM, generator=generator) * 2 - 1,
            "next": {
                "observation": randn(batch_size, OBS_DIM),
                "reward": (torch.rand(batch_size, 1, generator=generator) < 0.1).float(),
                "done": done,
                "terminated": done.clone(),
            },
        },
        [batch_size],
    )


def reference_update(learner: DualLearner, batch) -> dict:
    """The update as it was before the speed-up (generic loss paths)."""
    actor_loss = learner.actor_loss
    fast = actor_loss.fast_path
    actor_loss.fast_path = False
    try:
        critic = learner.critic
        q_loss, _ = critic.loss.qvalue_loss(batch)
        v_loss, _ = critic.loss.value_loss(batch)
        critic.optimizer.zero_grad(set_to_none=True)
        (q_loss + v_loss).backward()
        critic.optimizer.step()
        critic.target_updater.step()
        out = actor_loss(batch)
        learner.actor_optimizer.zero_grad(set_to_none=True)
        out["loss_actor"].backward()
        learner.actor_optimizer.step()
        learner.updates_since_refit += 1
        return {
            "loss_qvalue": q_loss.item(),
            "loss_value": v_loss.item(),
            **{k: v.item() for k, v in out.items()},
        }
    finally:
        actor_loss.fast_path = fast


def current_update(learner: DualLearner, batch) -> dict:
    return learner.update(batch)


def time_updates(fn, learner, batches) -> float:
    start = time.perf_counter()
    for batch in batches:
        fn(learner, batch)
    return len(batches) / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--updates", type=int, default=50, help="updates per round and path")
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument("--weighting", default="advantage")
    parser.add_argument("--profile", action="store_true", help="cProfile top list of each path")
    parser.add_argument("--top", type=int, default=25)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    learner = make_learner([f"actor.weighting={args.weighting}"])
    overrides = [f"actor.weighting={args.weighting}"]
    learners = {"reference": learner, "current": make_learner(overrides)}
    fns = {"reference": reference_update, "current": current_update}
    gen = torch.Generator().manual_seed(1)
    batch_size = learner.cfg.budget.batch_size
    batches = [random_batch(batch_size, gen) for _ in range(args.updates)]
    for name in fns:  # warm-up
        for batch in batches[:5]:
            fns[name](learners[name], batch)
    if args.profile:
        for name in fns:
            profiler = cProfile.Profile()
            profiler.enable()
            time_updates(fns[name], learners[name], batches)
            profiler.disable()
            print(f"==== {name} update: cProfile, {len(batches)} updates, by tottime")
            pstats.Stats(profiler).sort_stats("tottime").print_stats(args.top)
        return
    rates = {name: [] for name in fns}
    for _ in range(args.rounds):
        for name in fns:  # interleaved: both paths see the same machine load
            rates[name].append(time_updates(fns[name], learners[name], batches))
    ratios = [c / r for c, r in zip(rates["current"], rates["reference"], strict=True)]
    print(
        f"batch {batch_size}, weighting {args.weighting}, {args.threads} thread(s), "
        f"{args.rounds} rounds x {args.updates} updates"
    )
    for name in fns:
        r = sorted(rates[name])
        print(
            f"{name:>9}: {r[len(r) // 2]:7.1f} updates/s (median; min {r[0]:.1f}, max {r[-1]:.1f})"
        )
    ratios.sort()
    print(
        f"ratio current/reference: {ratios[len(ratios) // 2]:.2f}x (median of per-round ratios; "
        f"min {ratios[0]:.2f}, max {ratios[-1]:.2f})"
    )


if __name__ == "__main__":
    main()
