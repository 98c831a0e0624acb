"""DUAL's update and acting throughput on a device, eager against compiled, and what it
projects for ``budget=paper`` on AntMaze.

Times, in one process and at AntMaze's sizes (obs 31, action 8, horizon 8, width 256,
batch 256; the recipe's ``algo=dual`` settings), what one DUAL run repeats millions of
times:

* ``planner``: one Adam step of :class:`~torchrl_dual.DiffusionPlannerLoss` (Eq. 3);
* ``distillation``: one Adam step of :class:`~torchrl_dual.DistillationLoss` (Eq. 4-5);
* ``actor_critic``: one update as ``DualLearner.update`` composes it: TorchRL
  ``IQLLoss``'s Q and V losses, one Adam step and the soft target update, then one Adam
  step of :class:`~torchrl_dual.WeightedMAPActorLoss` (Eq. 7) on IQL's critics;
* ``act_b1`` / ``act_b64``: one call of DUAL's online policy
  (:func:`~torchrl_dual.make_dual_policy`: Laplace ensemble M = 5, Eq. 9, and shift-aware
  noise, Eq. 10, with the frozen transition model) on 1 and 64 states;
* ``laplace``: the posterior fit (Eq. 8) per 1000 transitions.

Each update and acting step runs ``eager``, ``compile`` (``torch.compile`` in
``--compile-mode``, default: its default mode; graph breaks allowed, their count reported) and ``cudagraphs`` (``compile`` then
tensordict's ``CudaGraphModule``, CUDA only). A mode that fails is reported with its
error, not hidden. The figures are steps per second (the device synchronised before and
after each timed block); the projection takes the fastest mode that ran.

The projection of one ``budget=paper`` AntMaze run (1M planner updates, 5 × 20k
distillation updates, 1M offline and 0.5M online actor-critic updates, 1M online steps, a
posterior refit every 10k updates over all transitions) adds two CPU-bound terms measured
on the CPU (docs/benchmarks.md, 2026-12-02): the env and collector cost of an online
step (``--env-step-ms``, 3.9 ms: the 5.2 ms online step less its 1.3 ms policy) and the
21 evaluations of 100 episodes (``--eval-hours``, 0.4 h).

Usage::

    python -m benchmarks.speed.gpu_throughput --device cuda --json gpu.json
    python -m benchmarks.speed.gpu_throughput --device cpu --quick --json cpu.json
    python -m benchmarks.speed.gpu_throughput --device cpu --modes eager --tiny   # a smoke test
    python -m benchmarks.speed.gpu_throughput --device cpu --only actor_critic \
        --compile-mode max-autotune-no-cudagraphs   # Inductor's own GEMMs tried too
"""

from __future__ import annotations

import argparse
import copy
import json
import platform
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import IQLLoss, SoftUpdate

from torchrl_dual import (
    DiffusionPlannerLoss,
    DistillationLoss,
    PlannerActor,
    TransitionModel,
    WeightedMAPActorLoss,
    make_dual_policy,
)
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout

MODES = ("eager", "compile", "cudagraphs")
UPDATES = ("planner", "distillation", "actor_critic")
ACTING = {"act_b1": 1, "act_b64": 64}


@dataclass
class Sizes:
    """AntMaze U-maze's shapes and ``budget=paper``'s networks (``algo=dual``)."""

    obs_dim: int = 31
    action_dim: int = 8
    horizon: int = 8
    hidden: int = 256
    depth: int = 3  # planner denoiser blocks (critics and V: 2 layers, as critic/iql.yaml)
    batch: int = 256
    teacher_steps: int = 32
    laplace_transitions: int = 65536


TINY = Sizes(obs_dim=5, action_dim=2, horizon=4, hidden=16, depth=1, batch=8,
             teacher_steps=4, laplace_transitions=512)  # fmt: skip


# ----------------------------------------------------------------------------- builders
def _planner(s: Sizes, num_steps: int, device: str) -> TrajectoryDiffusion:
    layout = TrajectoryLayout(s.obs_dim, s.action_dim, s.horizon)
    return TrajectoryDiffusion(layout, num_steps=num_steps, hidden=s.hidden, depth=s.depth).to(
        device
    )


def _windows(s: Sizes, device: str) -> TensorDict:
    rows = s.horizon + 1
    return TensorDict(
        observation=torch.randn(s.batch, rows, s.obs_dim, device=device),
        action=torch.rand(s.batch, rows, s.action_dim, device=device) * 2 - 1,
        batch_size=[s.batch, rows],
        device=device,
    )


def _transitions(s: Sizes, device: str) -> TensorDict:
    b = s.batch
    return TensorDict(
        observation=torch.randn(b, s.obs_dim, device=device),
        action=torch.rand(b, s.action_dim, device=device) * 2 - 1,
        next=TensorDict(
            observation=torch.randn(b, s.obs_dim, device=device),
            reward=torch.randn(b, 1, device=device),
            done=torch.zeros(b, 1, dtype=torch.bool, device=device),
            terminated=torch.zeros(b, 1, dtype=torch.bool, device=device),
            batch_size=[b],
        ),
        batch_size=[b],
        device=device,
    )


def _adam(params, capturable: bool) -> torch.optim.Adam:
    return torch.optim.Adam(params, lr=3e-4, capturable=capturable)


def _step(loss_fn: nn.Module, key: str, optimizer: torch.optim.Optimizer):
    def update(batch: TensorDict) -> TensorDict:
        out = loss_fn(batch)
        optimizer.zero_grad(set_to_none=True)
        out[key].backward()
        optimizer.step()
        return out.detach()

    return update


def build_planner(s: Sizes, device: str, capturable: bool):
    """One Adam step of Eq. 3 on a batch of ``H + 1``-row windows."""
    loss_fn = DiffusionPlannerLoss(_planner(s, s.teacher_steps, device))
    return _step(loss_fn, "loss_diffusion", _adam(loss_fn.parameters(), capturable)), _windows(
        s, device
    )


def build_distillation(s: Sizes, device: str, capturable: bool):
    """One Adam step of the first distillation round (N → N/2)."""
    teacher = _planner(s, s.teacher_steps, device)
    student = copy.deepcopy(teacher)
    student.num_steps = s.teacher_steps // 2
    loss_fn = DistillationLoss(student, teacher)
    optimizer = _adam(loss_fn.student_params.values(True, True), capturable)
    return _step(loss_fn, "loss_distillation", optimizer), _windows(s, device)


def _iql_critic(s: Sizes, device: str) -> IQLLoss:
    def mlp(inputs: int) -> MLP:
        return MLP(in_features=inputs, out_features=1, num_cells=[s.hidden] * 2,
                   activation_class=nn.ReLU)  # fmt: skip

    qvalue = ValueOperator(mlp(s.obs_dim + s.action_dim), in_keys=["observation", "action"])
    value = ValueOperator(mlp(s.obs_dim), in_keys=["observation"])
    stand_in = ProbabilisticActor(  # IQLLoss needs an actor slot; DUAL's is Eq. 7's loss
        TensorDictModule(_NoActor(), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"],
        distribution_class=torch.distributions.Normal,
    )
    loss = IQLLoss(stand_in, qvalue, value, expectile=0.9, num_qvalue_nets=2,
                   loss_function="l2").to(device)  # fmt: skip
    loss.make_value_estimator(gamma=0.99)
    return loss


class _NoActor(nn.Module):
    """A parameterless actor slot for ``IQLLoss`` (only its Q and V losses are used)."""

    def forward(self, observation: torch.Tensor):
        raise RuntimeError("DUAL's actor loss is WeightedMAPActorLoss (Eq. 7)")


def build_actor_critic(s: Sizes, device: str, capturable: bool):
    """``DualLearner.update``: IQL's Q + V step and soft update, then Eq. 7's actor step."""
    actor = PlannerActor(_planner(s, 1, device), init_std=0.3).to(device)
    critic = _iql_critic(s, device)
    critic_params = list(critic.qvalue_network_params.values(True, True)) + list(
        critic.value_network_params.values(True, True)
    )
    critic_optimizer = _adam(critic_params, capturable)
    target_updater = SoftUpdate(critic, tau=0.005)
    actor_loss = WeightedMAPActorLoss.from_iql(
        actor, critic, weighting="advantage", temperature=10.0, max_weight=100.0
    )
    actor_optimizer = _adam(actor.parameters(), capturable)

    def update(batch: TensorDict) -> TensorDict:
        q_loss, value_loss = critic.qvalue_loss(batch)[0], critic.value_loss(batch)[0]
        critic_optimizer.zero_grad(set_to_none=True)
        (q_loss + value_loss).backward()
        critic_optimizer.step()
        target_updater.step()
        out = actor_loss(batch)
        actor_optimizer.zero_grad(set_to_none=True)
        out["loss_actor"].backward()
        actor_optimizer.step()
        return TensorDict(loss_qvalue=q_loss.detach(), loss_value=value_loss.detach(),
                          loss_actor=out["loss_actor"].detach())  # fmt: skip

    return update, _transitions(s, device)


def build_policy(s: Sizes, device: str):
    """DUAL's online policy (Eq. 9-10), its posterior fitted on random states."""
    model = _planner(s, 1, device)
    actor = PlannerActor(model, init_std=0.3)
    spec = Bounded(-1.0, 1.0, shape=(s.action_dim,), device=device)
    policy = make_dual_policy(
        actor, spec, transition_model=TransitionModel.frozen_copy(model), shift_weight=0.5,
        device=device,
    )  # fmt: skip
    return policy


def _step_input(s: Sizes, batch: int, device: str) -> TensorDict:
    obs = torch.randn(batch, s.obs_dim, device=device)
    return TensorDict(
        observation=obs,
        previous_observation=obs + 0.1,
        previous_action=torch.zeros(batch, s.action_dim, device=device),
        previous_valid=torch.ones(batch, 1, dtype=torch.bool, device=device),
        batch_size=[batch],
        device=device,
    )


def _fit_batches(s: Sizes, device: str, chunk: int = 4096) -> list[TensorDict]:
    n = s.laplace_transitions
    return [
        TensorDict(
            observation=torch.randn(min(chunk, n - i), s.obs_dim, device=device),
            batch_size=[min(chunk, n - i)],
        )  # fmt: skip
        for i in range(0, n, chunk)
    ]


# ----------------------------------------------------------------------------- timing
def _sync(device: str) -> None:
    if device.startswith("cuda"):
        torch.cuda.synchronize()


def rate(fn: Callable[[], object], device: str, *, warmup: int, steps: int) -> float:
    """Calls per second of ``fn`` over ``steps`` calls after ``warmup`` calls."""
    for _ in range(warmup):
        fn()
    _sync(device)
    start = time.perf_counter()
    for _ in range(steps):
        fn()
    _sync(device)
    return steps / (time.perf_counter() - start)


def _graph_breaks() -> int:
    from torch._dynamo.utils import counters

    return sum(counters["graph_break"].values())


def wrap(fn: Callable, mode: str, device: str, compile_mode: str | None = None) -> Callable:
    """``fn`` as ``mode`` runs it (``compile``: ``torch.compile`` in ``compile_mode``;
    ``cudagraphs``: then ``CudaGraphModule``)."""
    if mode == "eager":
        return fn
    compiled = torch.compile(fn, mode=compile_mode)
    if mode == "compile":
        return compiled
    if not device.startswith("cuda"):
        raise RuntimeError("cudagraphs needs a CUDA device")
    from tensordict.nn import CudaGraphModule

    return CudaGraphModule(compiled, warmup=3)


def measure_all(
    s: Sizes,
    device: str,
    modes: tuple[str, ...],
    steps: int,
    warmup: int,
    on_result: Callable[[dict], None] = lambda results: None,
    only: tuple[str, ...] = (*UPDATES, *ACTING, "laplace"),
    compile_mode: str | None = None,
) -> dict:
    """Every figure of ``only``, mode by mode (all of ``eager`` first), calling
    ``on_result`` with the results so far after each one (a run cut short keeps what it
    measured)."""
    results: dict[str, dict] = {name: {} for name in (*UPDATES, *ACTING, "laplace")}
    builders = {"planner": build_planner, "distillation": build_distillation,
                "actor_critic": build_actor_critic}  # fmt: skip
    if "laplace" in only:
        results["laplace"] = {"eager": {"per_second_1k": _laplace_rate(s, device)}}
        print(f"laplace       eager       {results['laplace']['eager']}", flush=True)
    for mode in modes:
        for name in (n for n in (*UPDATES, *ACTING) if n in only):
            torch.manual_seed(0)
            torch._dynamo.reset()
            before = _graph_breaks()
            try:
                if name in builders:
                    update, batch = builders[name](s, device, capturable=mode == "cudagraphs")
                    fn = wrap(update, mode, device, compile_mode)
                    call = lambda fn=fn, batch=batch: fn(batch)  # noqa: E731
                else:
                    policy = build_policy(s, device)
                    policy[0].fit_laplace(_fit_batches(s, device))
                    step = _step_input(s, ACTING[name], device)

                    def act(td, policy=policy):
                        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
                            return policy(td)

                    act(step.clone())  # a collector's first step: caches built eagerly
                    fn = wrap(act, mode, device, compile_mode)
                    call = lambda fn=fn, step=step: fn(step.clone())  # noqa: E731
                per_second = rate(call, device, warmup=warmup, steps=steps)
                results[name][mode] = {
                    "per_second": per_second,
                    "graph_breaks": _graph_breaks() - before,
                }
            except Exception as error:  # a mode that does not run is a result too
                results[name][mode] = {"error": f"{type(error).__name__}: {str(error)[:300]}"}
            print(f"{name:13s} {mode:11s} {results[name][mode]}", flush=True)
            on_result(results)
    return results


def _laplace_rate(s: Sizes, device: str) -> float:
    """Posterior fits (Eq. 8) of 1000 transitions per second, over ``laplace_transitions``."""
    policy = build_policy(s, device)
    batches = _fit_batches(s, device)
    policy[0].fit_laplace(batches)  # warm-up
    _sync(device)
    start = time.perf_counter()
    policy[0].fit_laplace(batches)
    _sync(device)
    return s.laplace_transitions / 1000 / (time.perf_counter() - start)


# ----------------------------------------------------------------------------- projection
def best(results: dict, name: str) -> tuple[str | None, float]:
    """The fastest mode that ran: ``(mode, per second)``; ``(None, nan)`` if none did."""
    ran = {m: r["per_second"] for m, r in results[name].items() if "per_second" in r}
    if not ran:
        return None, float("nan")
    mode = max(ran, key=ran.get)
    return mode, ran[mode]


def project_paper(results: dict, env_step_ms: float, eval_hours: float) -> dict[str, float]:
    """Hours of one ``budget=paper`` AntMaze run from the measured rates (see the module
    docstring for the terms and the CPU-bound inputs)."""
    hours = {
        "planner": 1_000_000 / best(results, "planner")[1],
        "distillation": 100_000 / best(results, "distillation")[1],
        "actor_critic": 1_000_000 / best(results, "actor_critic")[1],
        # a fit after the offline phase, then every 10k of the 0.5M online updates over
        # 1M..2M transitions: about 1M + 50 x 1.5M = 76M transitions
        "laplace": 76_000 / results["laplace"]["eager"]["per_second_1k"],
        "online_updates": 500_000 / best(results, "actor_critic")[1],
        "online_steps": 1_000_000 * (env_step_ms / 1000 + 1 / best(results, "act_b1")[1]),
    }
    hours = {k: v / 3600 for k, v in hours.items()}
    hours["evaluation"] = eval_hours
    hours["total"] = sum(hours.values())
    return hours


def merge(paths: list[str], env_step_ms: float, eval_hours: float) -> dict:
    """One report of several runs' JSONs (e.g. each ``cudagraphs`` figure in its own
    process: a failed capture leaves the CUDA generator unusable for the next one)."""
    reports = [json.loads(open(p).read()) for p in paths]
    merged = dict(reports[0])
    results = merged["results"] = {k: dict(v) for k, v in reports[0]["results"].items()}
    for report in reports[1:]:
        for name, modes in report["results"].items():
            results.setdefault(name, {}).update(modes)
    names = (*UPDATES, *ACTING)
    merged["best_modes"] = {n: best(results, n)[0] for n in names}
    complete = all(merged["best_modes"].values()) and results.get("laplace")
    merged["paper_hours"] = project_paper(results, env_step_ms, eval_hours) if complete else None
    return merged


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--quick", action="store_true", help="fewer timed steps")
    parser.add_argument("--tiny", action="store_true", help="tiny networks (a smoke test)")
    parser.add_argument("--steps", type=int, default=None, help="timed calls per figure")
    parser.add_argument("--env-step-ms", type=float, default=3.9)
    parser.add_argument("--eval-hours", type=float, default=0.4)
    parser.add_argument(
        "--only",
        nargs="+",
        choices=(*UPDATES, *ACTING, "laplace"),
        default=None,
        help="these figures only",
    )
    parser.add_argument(
        "--compile-mode",
        default=None,
        help="torch.compile's mode (recipe: compile.compile_mode), e.g. max-autotune",
    )
    parser.add_argument("--json", default=None)
    parser.add_argument(
        "--merge", nargs="+", default=None, help="merge these JSONs into --json (no measurement)"
    )
    args = parser.parse_args(argv)
    if args.merge:
        report = merge(args.merge, args.env_step_ms, args.eval_hours)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(report, f, indent=1)
        print(json.dumps({k: report[k] for k in ("best_modes", "paper_hours")}, indent=1))
        return report
    modes = tuple(m for m in args.modes if m != "cudagraphs" or args.device.startswith("cuda"))
    sizes = TINY if args.tiny else Sizes()
    steps = args.steps or (5 if args.tiny else 30 if args.quick else 200)
    warmup = 2 if args.tiny else 10

    def report_of(results: dict) -> dict:
        return {
        "device": args.device,
        "device_name": torch.cuda.get_device_name() if args.device.startswith("cuda") else
        platform.processor() or platform.machine(),
        "torch": torch.__version__,
        "sizes": asdict(sizes),
        "steps": steps,
        "compile_mode": args.compile_mode,
        "results": results,
        "best_modes": {n: best(results, n)[0] for n in (*UPDATES, *ACTING)},
        "paper_hours": project_paper(results, args.env_step_ms, args.eval_hours)
        if all(best(results, n)[0] for n in (*UPDATES, *ACTING)) and results["laplace"]
        else None,
        "env_step_ms": args.env_step_ms,
        "eval_hours": args.eval_hours,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        }  # fmt: skip

    def write(results: dict) -> None:
        if args.json:
            with open(args.json, "w") as f:
                json.dump(report_of(results), f, indent=1)

    only = tuple(args.only or (*UPDATES, *ACTING, "laplace"))
    report = report_of(
        measure_all(sizes, args.device, modes, steps, warmup, write, only, args.compile_mode)
    )
    write(report["results"])
    print(json.dumps({k: report[k] for k in ("best_modes", "paper_hours")}, indent=1))
    return report


if __name__ == "__main__":
    main()
