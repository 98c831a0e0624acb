"""Does DUAL's epistemic uncertainty grow away from the offline data? (Eq. 7-9)

On a toy offline data set (2-D states from three clusters, actions a smooth function of the
state plus Gaussian noise) this script

1. trains a small actor with the weighted MAP loss of Eq. (7)
   (:class:`~torchrl_dual.objectives.WeightedMAPActorLoss`): by default DUAL's
   :class:`~torchrl_dual.modules.PlannerActor` on a one-step trajectory planner;
2. fits the last-layer Laplace posterior of Eq. (8) on the whole data set
   (:meth:`~torchrl_dual.modules.LaplaceEnsembleActor.fit_laplace`);
3. evaluates the epistemic std ``sqrt(mean_j Var_j)`` of Eq. (9) on test states at increasing
   distance from the data, two ways: the Monte-Carlo ensemble variance of
   :class:`~torchrl_dual.modules.LaplaceEnsembleActor` with a large ``M``, and the closed form
   ``laplace.predictive_variance(φ(s)) · readout_scale²`` (action units);
4. reports the Spearman correlation between the std and the distance to the nearest training
   state (goal: ≥ 0.5), prints a markdown summary and saves a plot.

Run (about 30 s on 2 CPU cores)::

    python -m benchmarks.studies.uncertainty --seed 0 --out docs/figures/uncertainty.png
"""

from __future__ import annotations

import argparse
import math
import shlex
import sys
import time
from pathlib import Path

import torch
from scipy.stats import spearmanr
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import LaplaceEnsembleActor, LinearHeadActor, PlannerActor
from torchrl_dual.objectives.weighted_map_actor import WeightedMAPActorLoss

CENTRES = torch.tensor([[-1.5, 0.0], [1.5, 0.0], [0.0, 1.5]])
CLUSTER_STD = 0.3
ACTION_NOISE = 0.1
DISTANCE_BINS = (0.0, 0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 5.0, math.inf)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--seed", type=int, default=0, help="seed of data, networks and sampling")
    parser.add_argument(
        "--out", type=Path, default=Path("docs/figures/uncertainty.png"), help="PNG to write"
    )
    parser.add_argument(
        "--actor",
        choices=("planner", "mlp"),
        default="planner",
        help="PlannerActor on a one-step planner (DUAL) or LinearHeadActor on an MLP (IQL + LA)",
    )
    parser.add_argument(
        "--weighting",
        choices=("uniform", "advantage"),
        default="uniform",
        help="Eq. (7) weights: uniform, or IQL advantage weights from an oracle critic",
    )
    parser.add_argument("--num-data", type=int, default=3000, help="offline transitions")
    parser.add_argument("--steps", type=int, default=1500, help="actor updates")
    parser.add_argument("--batch-size", type=int, default=256, help="actor batch size")
    parser.add_argument("--num-samples", type=int, default=2048, help="M of the MC estimate")
    parser.add_argument("--num-test", type=int, default=1000, help="test states")
    parser.add_argument("--threads", type=int, default=1, help="torch intra-op threads")
    return parser.parse_args(argv)


# ----------------------------------------------------------------------------- data
def behaviour_mean(observation: torch.Tensor) -> torch.Tensor:
    """The smooth data policy ``f(s)``: ``[sin(s_x) + 0.3 s_y, 0.5 cos(s_y) - 0.2 s_x]``."""
    x, y = observation[..., 0], observation[..., 1]
    return torch.stack([torch.sin(x) + 0.3 * y, 0.5 * torch.cos(y) - 0.2 * x], dim=-1)


def make_dataset(num: int, generator: torch.Generator) -> TensorDict:
    cluster = torch.randint(len(CENTRES), (num,), generator=generator)
    observation = CENTRES[cluster] + CLUSTER_STD * torch.randn(num, 2, generator=generator)
    action = behaviour_mean(observation) + ACTION_NOISE * torch.randn(num, 2, generator=generator)
    return TensorDict({"observation": observation, "action": action}, [num])


def make_test_states(num: int, generator: torch.Generator) -> torch.Tensor:
    """A fifth in-distribution, the rest uniform in a box reaching ~5 units past the data."""
    near = make_dataset(num // 5, generator)["observation"]
    far = (torch.rand(num - len(near), 2, generator=generator) * 2 - 1) * 6.0
    return torch.cat([near, far])


# ----------------------------------------------------------------------------- models
class _OracleCritic(nn.Module):
    """``Q(s, a) = -‖a − f(s)‖²`` and ``V(s) = E_{a∼data} Q = −A·noise²``."""

    def forward(self, observation: torch.Tensor, action: torch.Tensor | None = None):
        if action is None:
            return torch.full((*observation.shape[:-1], 1), -2 * ACTION_NOISE**2)
        return -(action - behaviour_mean(observation)).square().sum(-1, keepdim=True)


def make_actor(kind: str, data: TensorDict):
    if kind == "mlp":
        net = MLP(in_features=2, out_features=2, num_cells=[64, 64], activation_class=nn.ReLU)
        return LinearHeadActor(net, 2)
    model = TrajectoryDiffusion(TrajectoryLayout(2, 2, 4), num_steps=1, hidden=64, depth=2)
    model.normalizer.fit(data["observation"], data["action"])
    return PlannerActor(model)


def make_loss(actor, weighting: str) -> WeightedMAPActorLoss:
    if weighting == "uniform":
        return WeightedMAPActorLoss(actor, weighting="uniform")
    critic = _OracleCritic()
    return WeightedMAPActorLoss(
        actor,
        qvalue_network=TensorDictModule(
            critic, in_keys=["observation", "action"], out_keys=["state_action_value"]
        ),
        value_network=TensorDictModule(critic, in_keys=["observation"], out_keys=["state_value"]),
        weighting="advantage",
        temperature=10.0,
    )


def train(loss_fn: WeightedMAPActorLoss, data: TensorDict, args, generator) -> list[float]:
    optimizer = torch.optim.Adam(loss_fn.parameters(), lr=1e-3)
    history = []
    for _ in range(args.steps):
        index = torch.randint(len(data), (args.batch_size,), generator=generator)
        loss = loss_fn(data[index])["loss_actor"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(float(loss.detach()))
    return history


# ----------------------------------------------------------------------------- evaluation
@torch.no_grad()
def epistemic_std(policy: LaplaceEnsembleActor, states: torch.Tensor) -> tuple[torch.Tensor, ...]:
    """``sqrt(mean_j Var_j)`` in action units: Monte-Carlo (Eq. 9) and closed form (Eq. 8)."""
    with set_exploration_type(ExplorationType.RANDOM):
        out = policy(TensorDict({"observation": states}, [len(states)]))
    mc = out["epistemic_variance"].mean(-1).sqrt()
    features = policy.actor.features(states)
    variance = policy.laplace.predictive_variance(features) * policy.actor.readout_scale() ** 2
    return mc, variance.mean(-1).sqrt()


def binned(distance: torch.Tensor, std: torch.Tensor) -> list[tuple[str, int, float]]:
    rows = []
    for lo, hi in zip(DISTANCE_BINS[:-1], DISTANCE_BINS[1:], strict=True):
        inside = (distance >= lo) & (distance < hi)
        if inside.any():
            label = f"[{lo:g}, {hi:g})" if math.isfinite(hi) else f"≥ {lo:g}"
            rows.append((label, int(inside.sum()), float(std[inside].median())))
    return rows


def plot(distance, mc, closed, data_std, out: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2), dpi=120)
    ax.scatter(distance, closed, s=7, alpha=0.45, label="closed form (Eq. 8)", color="tab:blue")
    ax.scatter(
        distance, mc, s=7, alpha=0.45, marker="x", label="MC ensemble (Eq. 9)", color="tab:orange"
    )
    order = distance.argsort()
    window = max(len(order) // 25, 1)
    smooth = torch.nn.functional.avg_pool1d(closed[order][None, None], window, 1).flatten()
    ax.plot(
        distance[order][window // 2 : window // 2 + len(smooth)],
        smooth,
        color="black",
        lw=1.5,
        label="running mean (closed form)",
    )
    ax.axhline(data_std, color="grey", ls="--", lw=1, label="learnt aleatoric σ̄")
    ax.set_xlabel("distance to nearest training state")
    ax.set_ylabel("epistemic std (action units)")
    ax.set_yscale("log")
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)


# ----------------------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> dict:
    args = parse_args(argv)
    start = time.perf_counter()
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    generator = torch.Generator().manual_seed(args.seed)

    data = make_dataset(args.num_data, generator)
    actor = make_actor(args.actor, data)
    loss_fn = make_loss(actor, args.weighting)
    history = train(loss_fn, data, args, generator)  # Eq. (7)

    policy = LaplaceEnsembleActor(actor, num_samples=args.num_samples)
    weight_fn = None if args.weighting == "uniform" else loss_fn.advantage_weights
    laplace = policy.fit_laplace(data.split(500), weight_fn=weight_fn)  # Eq. (8)

    states = make_test_states(args.num_test, generator)
    distance = torch.cdist(states, data["observation"]).min(-1).values
    mc, closed = epistemic_std(policy, states)  # Eq. (9)
    rho_mc = spearmanr(mc.numpy(), distance.numpy()).statistic
    rho_closed = spearmanr(closed.numpy(), distance.numpy()).statistic
    off = distance > 0.5  # off-data states only: is the ordering kept beyond the support?
    rho_off = spearmanr(closed[off].numpy(), distance[off].numpy()).statistic
    agreement = float(((mc - closed).abs() / closed).median())
    sigma_bar = float(actor.std.detach().mean())
    elapsed = time.perf_counter() - start

    title = f"{args.actor} actor, {args.weighting} weights, seed {args.seed}"
    plot(distance, mc, closed, sigma_bar, args.out, title)

    command = "python -m benchmarks.studies.uncertainty " + " ".join(
        shlex.quote(a) for a in (sys.argv[1:] if argv is None else argv)
    )
    print(f"## Epistemic uncertainty vs distance to the data ({title})\n")
    print(f"Command: `{command.strip()}`  ")
    print(
        f"Data: {args.num_data} transitions, 3 clusters (std {CLUSTER_STD}), action noise "
        f"{ACTION_NOISE}; {args.steps} updates, final loss {history[-1]:.3f}, learnt σ̄ "
        f"{sigma_bar:.3f}; Laplace λ = {float(laplace.prior_precision):.3g}; M = "
        f"{args.num_samples}; {len(states)} test states; {elapsed:.1f} s.\n"
    )
    print("| estimate | Spearman ρ(std, distance) | goal |")
    print("|---|---|---|")
    print(f"| MC ensemble, Eq. (9) | {rho_mc:.3f} | ≥ 0.5 |")
    print(f"| closed form, Eq. (8) | {rho_closed:.3f} | ≥ 0.5 |")
    print(f"| closed form, only {int(off.sum())} states with d > 0.5 | {rho_off:.3f} | |\n")
    print(f"Median |MC − closed| / closed: {agreement:.3f}\n")
    print("| distance bin | states | median std (MC) | median std (closed form) |")
    print("|---|---|---|---|")
    for (label, count, s_mc), (_, _, s_cf) in zip(
        binned(distance, mc), binned(distance, closed), strict=True
    ):
        print(f"| {label} | {count} | {s_mc:.4f} | {s_cf:.4f} |")
    print(f"\nPlot: `{args.out}`")
    return {
        "spearman_mc": rho_mc,
        "spearman_closed": rho_closed,
        "spearman_off_data": rho_off,
        "agreement": agreement,
        "seconds": elapsed,
    }


if __name__ == "__main__":
    main()
