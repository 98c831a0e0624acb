"""Batch-1 action latency: Gaussian MLP actor vs the N-step planner vs the distilled planner.

Measures, in one process, the time one policy call takes on a ``[1, obs_dim]`` observation
(what an env step costs the agent). Distillation exists for speed (the action path is the
hot path), so the student is always timed next to its teacher.

Weights are untrained: the cost of a forward pass does not depend on the weight values,
only on the architecture and the number of sampling steps.

Candidates live in :data:`BUILDERS` (name -> builder). To add one, write
``def build_x(cfg) -> TensorDictModuleBase`` and register it; the table and the JSON
pick it up. ``dual_m5`` is DUAL's online policy (Laplace ensemble M = 5 + shift-aware
noise; the policy query and the frozen transition model's query in one batched pass);
``dual_m5_shared`` uses the actor's own weights for ``ŝ_t``; ``dual_m5_two_pass`` runs
the frozen transition model as a separate second pass; ``dual_m5_n8`` is the "w/o
distillation" ablation (an 8-step planner actor); ``dual_m5_latent`` the "w τ^N sampling"
ablation (``laplace.uq=latent``). The recipe's baselines act with their exploration
policies, built by the recipe's own builders with the actor settings of
``recipes/config/algo/<algo>.yaml`` and the width ``--hidden``: ``iql_actor``
(``algo=iql``), ``iql_la_m5`` (``algo=iql_la``), ``diffql_n5`` (``algo=diffql``) and
``diffql_la_m5`` (``algo=diffql_la``); ``algo=diffuser`` acts as ``planner_n32``. Every
candidate gets the step input a collector would give it mid-episode (:func:`step_input`).
Timings are interleaved (round-robin over candidates) so that load from other processes
affects every candidate alike.

Usage::

    python benchmarks/latency.py                          # PointMaze sizes, 1 thread
    python benchmarks/latency.py --threads 2 --json latency.json
    python benchmarks/latency.py --only planner_n1 mlp_actor --reps 2000
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictModuleBase, TensorDictSequential
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import (
    MLP,
    DiffusionActor,
    NormalParamExtractor,
    ProbabilisticActor,
    TanhNormal,
)

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import (
    DDPMLastStepActor,
    LaplaceEnsembleActor,
    LinearHeadActor,
    PlannerActor,
    PlannerPolicy,
    ShiftAwareNoise,
    TransitionModel,
    make_dual_policy,
)
from torchrl_dual.recipe.diffql import ActionBox, make_diffusion_actor
from torchrl_dual.recipe.iql import make_iql_actor

ALGO_CONFIGS = Path(__file__).resolve().parents[1] / "recipes" / "config" / "algo"


@dataclass
class Config:
    obs_dim: int = 6  # PointMaze: position, velocity, goal
    action_dim: int = 2
    horizon: int = 8  # H; the planner diffuses H + 1 rows (paper, Appendix A)
    hidden: int = 256  # width of the MLP actor and of the planner denoiser
    depth: int = 3  # MLP hidden layers / denoiser residual blocks
    teacher_steps: int = 32  # N of the teacher planner


# ----------------------------------------------------------------------------- builders
def build_mlp_actor(cfg: Config) -> TensorDictModuleBase:
    """TorchRL's Gaussian actor: MLP -> (loc, scale) -> TanhNormal."""
    net = torch.nn.Sequential(
        MLP(
            in_features=cfg.obs_dim,
            out_features=2 * cfg.action_dim,
            num_cells=[cfg.hidden] * cfg.depth,
            activation_class=torch.nn.SiLU,
        ),
        NormalParamExtractor(),
    )
    spec = Bounded(-1.0, 1.0, shape=(cfg.action_dim,))
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        spec=spec,
        distribution_class=TanhNormal,
        distribution_kwargs={"low": spec.space.low, "high": spec.space.high},
    )


def _planner(cfg: Config, num_steps: int) -> TensorDictModuleBase:
    layout = TrajectoryLayout(cfg.obs_dim, cfg.action_dim, cfg.horizon)
    model = TrajectoryDiffusion(layout, num_steps=num_steps, hidden=cfg.hidden, depth=cfg.depth)
    return PlannerPolicy(model, action_low=-1.0, action_high=1.0)


def build_planner_n32(cfg: Config) -> TensorDictModuleBase:
    """The teacher: ``TrajectoryDiffusion`` sampled with N DDIM steps."""
    return _planner(cfg, cfg.teacher_steps)


def build_planner_n1(cfg: Config) -> TensorDictModuleBase:
    """The distilled student: same architecture, one DDIM step."""
    return _planner(cfg, 1)


def _fit_data(cfg: Config) -> list[TensorDict]:
    """Random states to fit a Laplace posterior on (its values do not change the cost)."""
    return [TensorDict({"observation": torch.randn(512, cfg.obs_dim)}, [512])]


def _dual(
    cfg: Config, transition: str, num_steps: int = 1, uncertainty: str = "laplace"
) -> TensorDictModuleBase:
    """DUAL's acting policy from the library builder (:func:`make_dual_policy`), as the
    recipe assembles it; ``transition`` picks the source of ``ŝ_t``, ``num_steps`` the
    actor's (and the transition model's) sampling steps, ``uncertainty`` the ensemble
    (``laplace.uq``)."""
    layout = TrajectoryLayout(cfg.obs_dim, cfg.action_dim, cfg.horizon)
    model = TrajectoryDiffusion(layout, num_steps=num_steps, hidden=cfg.hidden, depth=cfg.depth)
    actor = PlannerActor(model)
    if transition == "shared":
        transition_model = TransitionModel(model, frozen=False)
    else:
        transition_model = TransitionModel.frozen_copy(model)
    spec = Bounded(-1.0, 1.0, shape=(cfg.action_dim,))
    fit_data = _fit_data(cfg)
    if uncertainty == "latent":  # no posterior: M planner latents per call
        return make_dual_policy(
            actor, spec, transition_model=transition_model, uncertainty="latent"
        )
    if transition == "two_pass":  # the generic composition: ŝ_t from its own module
        ensemble = LaplaceEnsembleActor(
            actor, num_samples=5, action_low=-1.0, action_high=1.0, sample_action=False
        )
        ensemble.fit_laplace(fit_data)
        return TensorDictSequential(ensemble, transition_model, ShiftAwareNoise(spec, 0.5))
    policy = make_dual_policy(actor, spec, transition_model=transition_model, shift_weight=0.5)
    policy[0].fit_laplace(fit_data)
    return policy


def build_dual_m5(cfg: Config) -> TensorDictModuleBase:
    """DUAL's online policy as the recipe builds it: one-step planner actor + Laplace
    ensemble (M = 5, Eq. 9) + shift-aware noise (Eq. 10), with the policy query for s_t
    and the frozen transition model's query for (s_(t-1), a_(t-1)) in one batched pass."""
    return _dual(cfg, "paired")


def build_dual_m5_shared(cfg: Config) -> TensorDictModuleBase:
    """As ``dual_m5`` with the actor's own weights as the transition model (Alg. 1's p_θ)."""
    return _dual(cfg, "shared")


def build_dual_m5_two_pass(cfg: Config) -> TensorDictModuleBase:
    """As ``dual_m5`` with the frozen transition model run as a second, separate pass."""
    return _dual(cfg, "two_pass")


def build_dual_m5_n8(cfg: Config) -> TensorDictModuleBase:
    """The "w/o distillation" ablation (``distillation.final_steps=8``): ``dual_m5`` with an
    8-step planner actor (7 DDIM steps, then the Laplace last step) and an 8-step frozen
    transition model, on the plain path (two passes)."""
    return _dual(cfg, "paired", num_steps=8)


def build_dual_m5_latent(cfg: Config) -> TensorDictModuleBase:
    """The "w τ^N sampling" ablation (``laplace.uq=latent``): ``dual_m5`` with the
    :class:`~torchrl_dual.modules.laplace.LatentEnsembleActor` (M = 5 planner latents per
    call, through the actor's MAP weights) in place of the Laplace heads."""
    return _dual(cfg, "paired", uncertainty="latent")


# ------------------------------------------------------------- the recipe's baselines
def _algo_cfg(cfg: Config, algo: str) -> DictConfig:
    """``recipes/config/algo/<algo>.yaml``'s ``actor`` (depth, ``N``, activation as the
    recipe runs them) with the width ``--hidden`` (``budget.network_width``), on CPU."""
    actor = OmegaConf.load(ALGO_CONFIGS / f"{algo}.yaml").actor
    actor.hidden = cfg.hidden  # replaces the ${budget.network_width} interpolation
    return OmegaConf.create({"actor": OmegaConf.to_container(actor), "device": "cpu"})


def _spec(cfg: Config) -> Bounded:
    return Bounded(-1.0, 1.0, shape=(cfg.action_dim,))


def build_iql_actor(cfg: Config) -> TensorDictModuleBase:
    """``algo=iql``'s actor and exploration policy: :func:`make_iql_actor` (MLP ``hidden``
    × 2, ReLU → ``NormalParamExtractor`` → ``TanhNormal``)."""
    return make_iql_actor(_algo_cfg(cfg, "iql"), cfg.obs_dim, _spec(cfg))


def build_iql_la_m5(cfg: Config) -> TensorDictModuleBase:
    """``algo=iql_la``'s exploration policy: ``LinearHeadActor.from_actor`` over the IQL
    actor (``algo/iql_la.yaml``), Laplace ensemble M = 5 (Eq. 9) and shift-aware noise
    with λ = 0, from :func:`make_dual_policy`; posterior fitted on random states."""
    head_actor = LinearHeadActor.from_actor(
        make_iql_actor(_algo_cfg(cfg, "iql_la"), cfg.obs_dim, _spec(cfg))
    )
    policy = make_dual_policy(head_actor, _spec(cfg), num_samples=5, shift_weight=0.0)
    policy[0].fit_laplace(_fit_data(cfg))
    return policy


def _diffusion_actor(cfg: Config, algo: str) -> DiffusionActor:
    return make_diffusion_actor(_algo_cfg(cfg, algo), cfg.obs_dim, cfg.action_dim)


def build_diffql_n5(cfg: Config) -> TensorDictModuleBase:
    """``algo=diffql``'s exploration policy: TorchRL ``DiffusionActor`` (``N = 5`` DDPM
    steps, score MLP ``hidden`` × 3, SiLU; :func:`make_diffusion_actor`) then the clamp to
    the action box."""
    spec = _spec(cfg)
    clamp = TensorDictModule(
        ActionBox(spec.space.low, spec.space.high), in_keys=["action"], out_keys=["action"]
    )
    return TensorDictSequential(_diffusion_actor(cfg, "diffql"), clamp)


def build_diffql_la_m5(cfg: Config) -> TensorDictModuleBase:
    """``algo=diffql_la``'s exploration policy: ``DDPMLastStepActor`` (the zero-latent
    chain, the score network's last layer as the Laplace layer) over ``diffql_n5``'s
    actor, Laplace ensemble M = 5 and λ = 0 noise, from :func:`make_dual_policy`."""
    last_step = DDPMLastStepActor(_diffusion_actor(cfg, "diffql_la"), latent="zero")
    policy = make_dual_policy(last_step, _spec(cfg), num_samples=5, shift_weight=0.0)
    policy[0].fit_laplace(_fit_data(cfg))
    return policy


BUILDERS: dict[str, Callable[[Config], TensorDictModuleBase]] = {
    "mlp_actor": build_mlp_actor,
    "planner_n32": build_planner_n32,
    "planner_n1": build_planner_n1,
    "dual_m5": build_dual_m5,
    "dual_m5_shared": build_dual_m5_shared,
    "dual_m5_two_pass": build_dual_m5_two_pass,
    "dual_m5_n8": build_dual_m5_n8,
    "dual_m5_latent": build_dual_m5_latent,
    "iql_actor": build_iql_actor,
    "iql_la_m5": build_iql_la_m5,
    "diffql_n5": build_diffql_n5,
    "diffql_la_m5": build_diffql_la_m5,
}
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
        "| name | median ms | p90 ms | ratio vs mlp_actor | ratio vs planner_n32 |",
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
        with open(args.json, "w") as f:
            json.dump(medians, f, indent=2)
    return medians


if __name__ == "__main__":
    main()
