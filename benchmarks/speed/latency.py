"""Batch-1 action latency: Gaussian MLP actor vs the N-step planner vs the distilled planner.

Measures, in one process, the time one policy call takes on a ``[1, obs_dim]`` observation
(what an env step costs the agent). Distillation exists for speed (the action path is the
hot path), so the student is always timed next to its teacher.

Weights are untrained: the cost of a forward pass does not depend on the weight values,
only on the architecture and the number of sampling steps.

Candidates live in ``latency_candidates.py``: :data:`BUILDERS` (name -> builder) and the
sizes :class:`Config`. To add one, write ``def build_x(cfg) -> TensorDictModuleBase``
there and register it; the table and the JSON pick it up. Every candidate gets the step
input a collector would give it mid-episode (:func:`step_input`).
Timings are interleaved (round-robin over candidates) so that load from other processes
affects every candidate alike.

Usage::

    python -m benchmarks.speed.latency                          # PointMaze sizes, 1 thread
    python -m benchmarks.speed.latency --threads 2 --json latency.json
    python -m benchmarks.speed.latency --only planner_n1 mlp_actor --reps 2000
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.provenance import write_json
from benchmarks.speed.latency_candidates import BUILDERS, Config

REFERENCES = ("mlp_actor", "planner_n32")


# ----------------------------------------------------------------------------- timing
def step_input(observation: torch.Tensor, action_dim: int) -> TensorDict:
    """What a collector hands the policy mid-episode: s_t and, from the
    :class:`~torchrl_dual.transforms.PreviousTransition` env transform, (s_(t-1), a_(t-1))."""
    batch = observation.shape[:-1]
    return TensorDict(
        observation=observation.clone(),
        previous_observation=observation + 0.1,
        previous_action=torch.zeros(*batch, action_dim),
        previous_valid=torch.ones(*batch, 1, dtype=torch.bool),
        batch_size=batch,
    )


def measure(
    policies: dict[str, TensorDictModuleBase],
    step: TensorDict,
    *,
    reps: int,
    warmup: int,
    rounds: int,
) -> dict[str, list[float]]:
    """Per-call wall times in ms, collected round-robin over the candidates."""
    tds = {name: step.clone() for name in policies}
    times: dict[str, list[float]] = {name: [] for name in policies}
    per_round = max(1, reps // rounds)
    with torch.no_grad():
        for name, policy in policies.items():
            for _ in range(warmup):
                policy(tds[name])
        for _ in range(rounds):
            for name, policy in policies.items():
                td = tds[name]
                for _ in range(per_round):
                    start = time.perf_counter_ns()
                    policy(td)
                    times[name].append((time.perf_counter_ns() - start) / 1e6)
    return times


def summarise(times: dict[str, list[float]]) -> dict[str, dict[str, float]]:
    rows = {}
    for name, values in times.items():
        rows[name] = {
            "median": statistics.median(values),
            "p90": statistics.quantiles(values, n=10)[-1],
        }
    return rows


def markdown_table(rows: dict[str, dict[str, float]]) -> str:
    def ratio(name, ref):
        return f"{rows[name]['median'] / rows[ref]['median']:.3g}" if ref in rows else "n/a"

    lines = [
        "| name | median ms | p90 ms | vs mlp_actor (ratio of medians) "
        "| vs planner_n32 (ratio of medians) |",
        "|---|---:|---:|---:|---:|",
    ]
    for name, row in rows.items():
        lines.append(
            f"| {name} | {row['median']:.3f} | {row['p90']:.3f} | "
            f"{ratio(name, 'mlp_actor')} | {ratio(name, 'planner_n32')} |"
        )
    return "\n".join(lines)


def report_goal(rows: dict, name: str, issue: str, *, within_mlp: float) -> None:
    """Prints whether ``name`` is >= 20x faster than planner_n32 and within
    ``within_mlp`` x of mlp_actor (the goals the issues set)."""
    if not {"mlp_actor", "planner_n32", name} <= set(rows):
        return
    speedup = rows["planner_n32"]["median"] / rows[name]["median"]
    overhead = rows[name]["median"] / rows["mlp_actor"]["median"]
    print(
        f"goal ({issue}): {name} >= 20x faster than planner_n32: {speedup:.1f}x "
        f"({'met' if speedup >= 20 else 'MISSED'}); within {within_mlp:g}x of mlp_actor: "
        f"{overhead:.2f}x ({'met' if overhead <= within_mlp else 'MISSED'})"
    )


def profile(policy: TensorDictModuleBase, step: TensorDict, reps: int, exploration) -> None:
    """Prints the functions where ``reps`` calls of ``policy`` spend their time."""
    import cProfile
    import pstats

    td = step.clone()
    profiler = cProfile.Profile()
    with torch.no_grad(), set_exploration_type(exploration):
        for _ in range(10):
            policy(td)
        profiler.enable()
        for _ in range(reps):
            policy(td)
        profiler.disable()
    print()
    pstats.Stats(profiler).sort_stats("tottime").print_stats(15)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    defaults = Config()
    parser.add_argument("--obs-dim", type=int, default=defaults.obs_dim)
    parser.add_argument("--action-dim", type=int, default=defaults.action_dim)
    parser.add_argument("--horizon", type=int, default=defaults.horizon)
    parser.add_argument("--hidden", type=int, default=defaults.hidden)
    parser.add_argument("--depth", type=int, default=defaults.depth)
    parser.add_argument("--teacher-steps", type=int, default=defaults.teacher_steps)
    parser.add_argument("--threads", type=int, default=1, help="torch.set_num_threads")
    parser.add_argument("--reps", type=int, default=1000, help="timed calls per candidate")
    parser.add_argument("--warmup", type=int, default=50, help="untimed calls per candidate")
    parser.add_argument("--rounds", type=int, default=30, help="round-robin rounds")
    parser.add_argument(
        "--exploration",
        choices=("random", "deterministic"),
        default="random",
        help="exploration type during timing (random = data collection)",
    )
    parser.add_argument("--only", nargs="+", choices=sorted(BUILDERS), default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="PATH", help="write {name: median_ms} here")
    parser.add_argument(
        "--profile",
        metavar="NAME",
        choices=sorted(BUILDERS),
        help="after timing, print a cProfile of --reps calls of this candidate",
    )
    args = parser.parse_args(argv)

    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    cfg = Config(
        args.obs_dim, args.action_dim, args.horizon, args.hidden, args.depth, args.teacher_steps
    )
    names = args.only or list(BUILDERS)
    policies = {name: BUILDERS[name](cfg).eval() for name in names}
    step = step_input(torch.randn(1, cfg.obs_dim), cfg.action_dim)
    exploration = {"random": ExplorationType.RANDOM, "deterministic": ExplorationType.DETERMINISTIC}
    with set_exploration_type(exploration[args.exploration]):
        times = measure(policies, step, reps=args.reps, warmup=args.warmup, rounds=args.rounds)
    rows = summarise(times)

    print(
        f"batch-1 policy latency | torch {torch.__version__} | threads={torch.get_num_threads()} "
        f"| {platform.processor() or platform.machine()} | obs_dim={cfg.obs_dim} "
        f"action_dim={cfg.action_dim} horizon={cfg.horizon} hidden={cfg.hidden} "
        f"depth={cfg.depth} | exploration={args.exploration} | {args.reps} reps after "
        f"{args.warmup} warm-up | untrained weights (latency does not depend on them)\n"
    )
    print(markdown_table(rows))
    print()
    report_goal(rows, "planner_n1", "distillation issue", within_mlp=2.0)
    report_goal(rows, "dual_m5", "restructuring issue #8", within_mlp=1.3)
    medians = {name: row["median"] for name, row in rows.items()}
    if args.profile:
        profile(
            BUILDERS[args.profile](cfg).eval(),
            step,
            args.reps,
            exploration[args.exploration],
        )
    if args.json:
        write_json(args.json, medians, indent=2)
    return medians


if __name__ == "__main__":
    main()
