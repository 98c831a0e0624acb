"""Does DUAL's shift signal ``d_t`` (Eq. 10) see a dynamics shift?

``d_t = ‖ŝ_t − s_t‖`` compares the transition model's prediction for the current state
with the state the env returned. It can only steer exploration towards shifted dynamics
if it is larger there than where the model is merely imprecise. For a DUAL run directory
this script prints ``d`` on three kinds of transitions, with the run's own transition
model:

* ``offline``: a sample of ``D_offline`` (the model's error on the data it was fitted on);
* ``online <shift>``: the run's exploration policy acting in its env kit's train env
  without a shift (``none``) and under each ``--shifts`` entry (``env.shift=``), the
  steps right after a reset (no previous step, ``d_t = 0``) left out.

Each line gives the mean, the median and the 90th percentile of ``d``, and the mean
relative to the offline mean. With ``λ = exploration.shift_weight`` the executed
variance gains ``λ d_t`` (Eq. 10), also listed; the online lines add the policy's Eq. 9
std ``σ_θ`` and the executed std ``sqrt(σ_θ² + λ d_t)``, to set ``λ d_t`` against.

    python -m benchmarks.studies.shift_signal outputs/suite/default/umaze/dual/seed0
    python -m benchmarks.studies.shift_signal RUN_DIR --shifts rotation damping mass --steps 3000 --json out.json

The run directory is read only (its checkpoint is loaded from a temporary copy).
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.provenance import write_json
from benchmarks.studies.critic_calibration import load_run
from torchrl_dual.recipe import O2ORun
from torchrl_dual.recipe.kits.build import make_train_env


def offline_distance(run: O2ORun, samples: int, seed: int = 0) -> torch.Tensor:
    """``‖ŝ' − s'‖`` of the run's transition model on ``samples`` offline transitions
    (:meth:`~torchrl_dual.recipe.DualLearner.offline_shift_distances`)."""
    return run.learner.offline_shift_distances(samples, seed)


@torch.no_grad()
def online_rollout(run: O2ORun, shift: str, steps: int, seed: int = 0) -> TensorDictBase:
    """``steps`` env steps of the run's exploration policy in its train env with
    ``env.shift=shift``, without the steps that have no previous step (after a reset)."""
    settings = copy.deepcopy(run.settings)
    settings.env.shift = shift
    env = make_train_env(settings, run.data)
    env.set_seed(seed)
    with set_exploration_type(ExplorationType.RANDOM):
        rollout = env.rollout(steps, run.learner.policy, break_when_any_done=False)
    env.close()
    return rollout[rollout["previous_valid"].reshape(-1)].cpu()


def online_distance(run: O2ORun, shift: str, steps: int, seed: int = 0) -> torch.Tensor:
    """``d_t`` the policy computed on :func:`online_rollout`'s steps."""
    return online_rollout(run, shift, steps, seed)["shift_distance"].reshape(-1)


def summary(d: torch.Tensor, offline_mean: float, weight: float) -> dict[str, float]:
    """Mean, median, 90th percentile, mean / offline mean and ``λ · mean``."""
    mean = float(d.mean())
    return {
        "n": len(d),
        "mean": mean,
        "median": float(d.median()),
        "p90": float(d.quantile(0.9)),
        "vs_offline": mean / offline_mean,
        "lambda_d": weight * mean,
    }


def action_stds(rollout: TensorDictBase) -> dict[str, float]:
    """The Eq. 9 ensemble std ``σ_θ(s)`` and the executed ``sqrt(σ² + λ d_t)`` (Eq. 10),
    averaged over steps and action dimensions."""
    return {
        "policy_std": float(rollout["scale"].mean()),
        "executed_std": float(rollout["exploration_scale"].mean()),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", nargs="+", type=Path)
    parser.add_argument("--shifts", nargs="*", default=["rotation", "damping", "mass"])
    parser.add_argument("--samples", type=int, default=20000, help="offline transitions")
    parser.add_argument("--steps", type=int, default=3000, help="env steps per shift")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    rows: dict[str, dict[str, dict]] = {}
    for run_dir in args.run_dirs:
        if not (run_dir / "checkpoint.pt").is_file():
            print(f"error: {run_dir} has no checkpoint.pt (a run directory of the recipe)")
            return 2
        with tempfile.TemporaryDirectory() as workdir:
            run = load_run(run_dir, Path(workdir))
            if not hasattr(run.learner, "transition"):
                print(f"error: {run_dir} is not a DUAL run (algo={run.settings.algo})")
                return 2
            weight = float(run.settings.exploration.shift_weight)
            offline = offline_distance(run, args.samples)
            base = float(offline.mean())
            table = {"offline": summary(offline, base, weight)}
            for shift in ["none", *args.shifts]:
                rollout = online_rollout(run, shift, args.steps)
                d = rollout["shift_distance"].reshape(-1)
                table[f"online {shift}"] = {**summary(d, base, weight), **action_stds(rollout)}
        rows[str(run_dir)] = table
        print(f"\n{run_dir} (frames {run.frames}, λ = {weight:g})")
        print(f"{'transitions':<18} {'n':>6} {'mean d':>7} {'median':>7} {'p90':>7} "
              f"{'/ offline':>9} {'λ·mean':>7} {'σ_θ':>6} {'executed':>8}")  # fmt: skip
        for name, s in table.items():
            stds = f"{s['policy_std']:>6.3f} {s['executed_std']:>8.3f}" if "policy_std" in s else ""
            print(
                f"{name:<18} {s['n']:>6} {s['mean']:>7.3f} {s['median']:>7.3f} "
                f"{s['p90']:>7.3f} {s['vs_offline']:>8.2f}x {s['lambda_d']:>7.3f} {stds}"
            )
    if args.json is not None:
        write_json(args.json, rows, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
