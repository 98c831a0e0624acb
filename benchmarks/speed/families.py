"""Cost of DUAL per env family on this machine, and the paper budget's projected wall time.

    python -m benchmarks.speed.families                          # every family, default networks
    python -m benchmarks.speed.families --families antmaze hopper --updates 200 --json out.json

For each family (AntMaze, the three MuJoCo robots, Adroit pen) a stand-in Minari data set
(:func:`~torchrl_dual.data.write_standin_dataset`: the published id, env version and
observation/action sizes, random actions) is written to a temporary
``MINARI_DATASETS_PATH`` and ``recipes/o2o.py env=<family>`` runs in this process with the
default budget's networks and batch (width 256, batch 256) but ``--updates`` updates per
offline stage. From the run's CPU clocks (``stage_cpu_seconds``) it reports milliseconds
per planner update, per distillation update, per actor-critic update and per 1000
transitions of a Laplace fit; then it times the online env stepped by DUAL's exploration
policy (M = 5 ensemble + shift-aware noise, one batched forward per step), a raw
Gymnasium step of the data set's evaluation env, and the evaluation's cost per episode step
(a raw step plus 1/100 of the deterministic policy's forward on 100 episodes side by side). The projection multiplies these by ``budget=paper`` (1M planner updates,
5 × 20k distillation updates, 1M actor-critic updates, 1M online frames at UTD 0.5 with
a Laplace refit every 10k updates over all transitions, 21 evaluations of 100 episodes of
the time limit). Single-process, one thread: a GPU or more cores change every line.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.provenance import write_json
from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR

REPO = Path(__file__).resolve().parents[2]
FAMILIES = {  # env= override -> stand-in data set id
    "antmaze": ("env=antmaze", "D4RL/antmaze/umaze-v1"),
    "hopper": ("env=hopper", "mujoco/hopper/medium-v0"),
    "halfcheetah": ("env=halfcheetah", "mujoco/halfcheetah/medium-v0"),
    "walker2d": ("env=walker2d", "mujoco/walker2d/medium-v0"),
    "pen": ("env=adroit", "D4RL/pen/cloned-v2"),
}
PAPER = {
    "planner_updates": 1_000_000,
    "distill_updates": 5 * 20_000,
    "offline_updates": 1_000_000,
    "online_frames": 1_000_000,
    "utd_ratio": 0.5,
    "refit_every": 10_000,
    "dataset_transitions": 1_000_000,
    "evaluations": 21,
    "eval_episodes": 100,
}


def cpu_ms(run, stage: str, count: int) -> float:
    return 1000.0 * run.stage_cpu_seconds.get(stage, float("nan")) / max(count, 1)


def time_steps(step, count: int) -> float:
    """CPU milliseconds per call of ``step`` (after 10 warm-up calls)."""
    for _ in range(10):
        step()
    start = time.process_time()
    for _ in range(count):
        step()
    return 1000.0 * (time.process_time() - start) / count


def measure(family: str, updates: int, steps: int, workdir: Path) -> dict:
    from torchrl_dual.data import write_standin_dataset
    from torchrl_dual.recipe import compose_checked, run

    env_override, dataset_id = FAMILIES[family]
    write_standin_dataset(dataset_id, num_episodes=12, steps=100)
    overrides = [
        env_override,
        "budget=default",
        f"budget.planner_updates={updates}",
        f"budget.distill_updates=[{','.join([str(max(updates // 5, 1))] * 5)}]",
        f"budget.offline_updates={updates}",
        "budget.online_frames=0",
        "budget.eval_episodes=1",
        "env.max_episode_steps=100",
        "num_threads=1",
        "progress=false",
        f"output_dir={workdir / family}",
    ]
    o2o = run(compose_checked(RECIPE_CONFIG_DIR, overrides))
    transitions = len(o2o.data)
    result = {
        "family": family,
        "dataset_id": dataset_id,
        "obs_dim": o2o.data.obs_dim,
        "action_dim": o2o.data.action_dim,
        "planner_update_ms": cpu_ms(o2o, "planner", updates),
        "distill_update_ms": cpu_ms(o2o, "distillation", 5 * max(updates // 5, 1)),
        "actor_critic_update_ms": cpu_ms(o2o, "actor_critic", updates),
        "laplace_ms_per_1k_transitions": cpu_ms(o2o, "laplace", 1) * 1000 / transitions,
    }
    # the online hot path: env step + DUAL's exploration policy (one batched forward)
    env, policy = o2o.env, o2o.learner.exploration_policy
    state = {"td": env.reset()}

    def online_step() -> None:
        with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
            td = env.step(policy(state["td"]))
        state["td"] = env.step_mdp(td) if not td["next", "done"].any() else env.reset()

    result["online_step_ms"] = time_steps(online_step, steps)
    # a raw Gymnasium step with random actions (the data set's env behind its observation map)
    from torchrl_dual.recipe.kits.minari_families import minari_gym_env

    raw = minari_gym_env(o2o.settings, o2o.data, eval_env=True, shifted=False)
    raw.reset(seed=0)

    def raw_step() -> None:
        _, _, terminated, truncated, _ = raw.step(raw.action_space.sample())
        if terminated or truncated:
            raw.reset()

    result["gym_step_ms"] = time_steps(raw_step, steps)
    # evaluation: per episode-step, one raw step plus 1/E of the deterministic policy's
    # forward on the E = 100 episodes evaluate_episodes runs side by side
    batch = TensorDict(
        {"observation": torch.zeros(PAPER["eval_episodes"], o2o.data.obs_dim)},
        batch_size=[PAPER["eval_episodes"]],
    )

    def evaluation_forward() -> None:
        with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
            o2o.learner.evaluation_policy(batch)

    forward_ms = time_steps(evaluation_forward, max(steps // 10, 10))
    result["eval_step_ms"] = result["gym_step_ms"] + forward_ms / PAPER["eval_episodes"]
    return result


def projection_hours(m: dict, max_episode_steps: int) -> dict:
    """The paper budget's CPU hours per part from one family's measurements."""
    online_updates = PAPER["online_frames"] * PAPER["utd_ratio"]
    refits = online_updates / PAPER["refit_every"]
    transitions = PAPER["dataset_transitions"] + PAPER["online_frames"] / 2  # mean over refits
    parts_ms = {
        "planner": PAPER["planner_updates"] * m["planner_update_ms"],
        "distillation": PAPER["distill_updates"] * m["distill_update_ms"],
        "actor_critic": PAPER["offline_updates"] * m["actor_critic_update_ms"],
        "laplace": (1 + refits) * transitions / 1000 * m["laplace_ms_per_1k_transitions"],
        "online_updates": online_updates * m["actor_critic_update_ms"],
        "online_steps": PAPER["online_frames"] * m["online_step_ms"],
        "evaluation": PAPER["evaluations"]
        * PAPER["eval_episodes"]
        * max_episode_steps
        * m["eval_step_ms"],
    }
    hours = {k: v / 3.6e6 for k, v in parts_ms.items()}
    hours["total"] = sum(hours.values())
    return hours


TIME_LIMITS = {"antmaze": 700, "hopper": 1000, "halfcheetah": 1000, "walker2d": 1000, "pen": 100}
"""Time limits of the published data sets' evaluation envs (AntMaze U-maze 700; medium
and large mazes 1000; D4RL pen 100)."""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--families", nargs="+", choices=list(FAMILIES), default=list(FAMILIES))
    parser.add_argument("--updates", type=int, default=200, help="updates per offline stage")
    parser.add_argument("--steps", type=int, default=500, help="timed env steps")
    parser.add_argument("--json", type=Path, help="write the measurements here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["MINARI_DATASETS_PATH"] = str(Path(tmp) / "minari")
        rows = [measure(f, args.updates, args.steps, Path(tmp) / "runs") for f in args.families]
    for row in rows:
        row["paper_budget_cpu_hours"] = projection_hours(row, TIME_LIMITS[row["family"]])
    print(f"\n{platform.platform()}, {os.cpu_count()} CPUs, torch {torch.__version__}, 1 thread")
    print(
        "\nCPU ms per planner / distillation / actor-critic update, Laplace fit per 1k transitions,"
    )
    print(
        "online step (env + DUAL's M = 5 policy), evaluation step (per episode, 100 side by side),\nraw Gymnasium step:\n"
    )
    head = "| family | obs / act | planner | distill | actor-critic | Laplace /1k | online step | eval step | gym step |"
    print(head + "\n|" + "---|" * 9)
    for r in rows:
        print(
            f"| {r['family']} | {r['obs_dim']} / {r['action_dim']} | {r['planner_update_ms']:.1f} "
            f"| {r['distill_update_ms']:.1f} | {r['actor_critic_update_ms']:.1f} "
            f"| {r['laplace_ms_per_1k_transitions']:.1f} | {r['online_step_ms']:.2f} "
            f"| {r['eval_step_ms']:.2f} | {r['gym_step_ms']:.3f} |"
        )
    print("\nProjected CPU hours of budget=paper (one core, one seed):\n")
    parts = list(rows[0]["paper_budget_cpu_hours"])
    print("| family | " + " | ".join(parts) + " |\n|" + "---|" * (len(parts) + 1))
    for r in rows:
        hours = r["paper_budget_cpu_hours"]
        print(f"| {r['family']} | " + " | ".join(f"{hours[p]:.1f}" for p in parts) + " |")
    if args.json is not None:
        write_json(args.json, rows, indent=1, default=float)
        print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
