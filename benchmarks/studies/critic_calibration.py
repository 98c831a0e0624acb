"""How a run's critic values the offline data: its Q against the data's Monte-Carlo returns.

Cal-QL's premise (Nakamoto et al. 2023, Sec. 4) is a critic *calibrated* against the data's
behaviour: ``Q(s, a) ≥ G(s, a)``, the Monte-Carlo return-to-go, where CQL's penalty alone
pushes Q of the data's own actions below what they earned. This script loads a run's
checkpoint (any algorithm and critic of the recipe) and, on a sample of ``D_offline``,
prints the mean return-to-go ``G``, the critic's ``min_k Q_k`` at the data action and at
the learner's deterministic action ``π(s)``, the share of transitions where
``Q(s, a) < G`` (underestimated), and the correlation of Q with G.

``G`` is :func:`~torchrl_dual.data.monte_carlo_returns` with the critic's discount (the
bound Cal-QL trains with): it stops at the end of each episode, also at a time limit,
where the critic bootstraps past it. On a time-limited task whose reward goes on after
the limit (PointMaze's continuing goal reward) ``Q > G`` is therefore expected near the
ends of episodes, and the share ``Q < G`` is a lower bound on how often Q underestimates.

    python -m benchmarks.studies.critic_calibration outputs/suite/default/umaze_baselines/calql/seed0
    python -m benchmarks.studies.critic_calibration RUN_DIR [RUN_DIR ...] --samples 20000 --json out.json

The run directory is read only: its checkpoint is loaded from a temporary copy.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict, TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.objectives.utils import _vmap_func  # TorchRL's own ensemble evaluation

from benchmarks.provenance import write_json
from torchrl_dual.data import monte_carlo_returns
from torchrl_dual.recipe import ALGORITHMS, O2ORun


def min_q(loss, batch: TensorDictBase) -> torch.Tensor:
    """``min_k Q_k(s, a)`` over the loss's current Q networks, shape ``[B]``: all members
    in one vmapped call (TorchRL's ``_vmap_func``, as the losses and the actor loss do)."""
    params = loss.qvalue_network_params.detach()
    td = batch.select("observation", "action")
    values = _vmap_func(loss.qvalue_network, (None, 0))(td, params)["state_action_value"]
    return values.reshape(params.batch_size[0], -1).min(0).values


def load_run(run_dir: Path, workdir: Path) -> O2ORun:
    """The run of ``run_dir`` rebuilt from its composed config and checkpoint (copied into
    ``workdir``, where the rebuilt run writes its logger files)."""
    cfg = OmegaConf.load(run_dir / ".hydra" / "config.yaml")
    shutil.copy(run_dir / "checkpoint.pt", workdir / "checkpoint.pt")
    overrides = {"output_dir": str(workdir), "resume": True, "progress": False}
    cfg = OmegaConf.merge(cfg, overrides)
    return O2ORun(cfg, ALGORITHMS[str(cfg.algo)].learner)


@torch.no_grad()
def calibration(run: O2ORun, samples: int, seed: int = 0) -> dict[str, float]:
    """The figures of the module docstring on ``samples`` offline transitions."""
    data = run.data.transitions
    returns = monte_carlo_returns(data, float(run.settings.critic.discount)).reshape(-1).float()
    gen = torch.Generator().manual_seed(seed)
    index = torch.randperm(len(data), generator=gen)[: min(samples, len(data))]
    batch = data[index].to(run.settings.device)
    target = returns[index]
    loss = run.learner.critic.loss
    q_data = min_q(loss, batch).cpu()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        acted = run.learner.evaluation_policy(
            TensorDict({"observation": batch["observation"]}, [len(batch)])
        )
    q_policy = min_q(loss, batch.clone(False).set("action", acted["action"])).cpu()
    correlation = torch.corrcoef(torch.stack([q_data, target]))[0, 1]
    return {
        "transitions": len(index),
        "mc_return": float(target.mean()),
        "q_data": float(q_data.mean()),
        "q_policy": float(q_policy.mean()),
        "underestimated": float((q_data < target).float().mean()),
        "corr_q_mc": float(correlation),
        "frames": run.frames,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("run_dirs", nargs="+", type=Path)
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    rows = {}
    header = (
        f"{'run':<60} {'frames':>7} {'G':>7} {'Q(s,a)':>7} {'Q(s,π)':>7} {'Q<G':>6} {'corr':>6}"
    )
    print(header)
    for run_dir in args.run_dirs:
        if not (run_dir / "checkpoint.pt").is_file():
            print(f"error: {run_dir} has no checkpoint.pt (a run directory of the recipe)")
            return 2
        with tempfile.TemporaryDirectory() as workdir:
            figures = calibration(load_run(run_dir, Path(workdir)), args.samples)
        rows[str(run_dir)] = figures
        print(
            f"{str(run_dir)[-60:]:<60} {figures['frames']:>7} {figures['mc_return']:>7.2f} "
            f"{figures['q_data']:>7.2f} {figures['q_policy']:>7.2f} "
            f"{figures['underestimated']:>6.2f} {figures['corr_q_mc']:>6.2f}"
        )
    if args.json is not None:
        write_json(args.json, rows, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
