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

The projection of one ``budget=paper`` AntMaze run from these rates, and ``--merge`` of
several runs' JSONs, are in ``gpu_projection.py``; the timed workloads are built in
``gpu_workloads.py``.

Usage::

    python -m benchmarks.speed.gpu_throughput --device cuda --json gpu.json
    python -m benchmarks.speed.gpu_throughput --device cpu --quick --json cpu.json
    python -m benchmarks.speed.gpu_throughput --device cpu --modes eager --tiny   # a smoke test
    python -m benchmarks.speed.gpu_throughput --device cpu --only actor_critic \
        --compile-mode max-autotune-no-cudagraphs   # Inductor's own GEMMs tried too
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from collections.abc import Callable
from dataclasses import asdict

import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.provenance import with_provenance
from benchmarks.speed.gpu_projection import (
    ACTING,
    UPDATES,
    best,
    best_modes,
    merge,
    paper_hours,
    project_from_probe,
    project_paper,
)
from benchmarks.speed.gpu_workloads import (
    TINY,
    Sizes,
    build_actor_critic,
    build_distillation,
    build_planner,
    build_policy,
    fit_batches,
    step_input,
)

__all__ = [  # what this module has always offered (the rest moved beside it)
    "ACTING", "MODES", "TINY", "UPDATES", "Sizes", "best", "build_actor_critic",
    "build_distillation", "build_planner", "build_policy", "main", "measure_all", "merge",
    "project_paper", "rate", "wrap",
]  # fmt: skip

MODES = ("eager", "compile", "cudagraphs")


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
                    policy[0].fit_laplace(fit_batches(s, device))
                    step = step_input(s, ACTING[name], device)

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
    batches = fit_batches(s, device)
    policy[0].fit_laplace(batches)  # warm-up
    _sync(device)
    start = time.perf_counter()
    policy[0].fit_laplace(batches)
    _sync(device)
    return s.laplace_transitions / 1000 / (time.perf_counter() - start)


def printed(report: dict) -> dict:
    """What is printed at the end: the best modes and the projections (no input labels)."""
    keys = ("best_modes", "paper_hours", "paper_hours_end_to_end")
    return {
        k: {n: v for n, v in report[k].items() if n != "inputs"}
        if isinstance(report[k], dict)
        else report[k]
        for k in keys
        if k in report
    }


def with_probe(report: dict, probe: str | None) -> dict:
    """``report`` with ``paper_hours_end_to_end``: ``budget=paper`` projected from an
    ``e2e_probe.py`` JSON's measured figures only (``paper_hours`` is the projection from
    this script's update rates, the probe-free ``--env-step-ms`` and ``--eval-hours``)."""
    if probe is None:
        return report
    with open(probe) as f:
        return {**report, "paper_hours_end_to_end": project_from_probe(json.load(f))}


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
        "--probe",
        default=None,
        help="an e2e_probe.py JSON: also project budget=paper from its measured figures only",
    )
    parser.add_argument(
        "--merge", nargs="+", default=None, help="merge these JSONs into --json (no measurement)"
    )
    args = parser.parse_args(argv)
    if args.merge:
        report = with_probe(merge(args.merge, args.env_step_ms, args.eval_hours), args.probe)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(with_provenance(report), f, indent=1)
        print(json.dumps(printed(report), indent=1))
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
        "best_modes": best_modes(results),
        "paper_hours": paper_hours(results, args.env_step_ms, args.eval_hours),
        "env_step_ms": args.env_step_ms,
        "eval_hours": args.eval_hours,
        "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        }  # fmt: skip

    def write(results: dict) -> None:
        if args.json:
            with open(args.json, "w") as f:
                json.dump(with_provenance(report_of(results)), f, indent=1)

    only = tuple(args.only or (*UPDATES, *ACTING, "laplace"))
    report = report_of(
        measure_all(sizes, args.device, modes, steps, warmup, write, only, args.compile_mode)
    )
    write(report["results"])
    report = with_probe(report, args.probe)
    if args.probe and args.json:
        with open(args.json, "w") as f:
            json.dump(with_provenance(report), f, indent=1)
    print(json.dumps(printed(report), indent=1))
    return report


if __name__ == "__main__":
    main()
