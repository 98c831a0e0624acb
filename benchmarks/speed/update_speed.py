"""CPU ms per update of the recipe's IQL, Cal-QL and DUAL actor+critic updates against
d3rlpy's IQL and Cal-QL updates on the same batches (issue 40, items 1 and 2; the
"Update speed against d3rlpy" section of docs/benchmarks.md).

    python -m benchmarks.speed.update_speed                          # 256 x 2, batch 256, ~3 min
    python -m benchmarks.speed.update_speed --rounds 7 --json benchmarks/results/update_speed.json
    python -m benchmarks.speed.update_speed --profile 50             # + where our updates spend time
    python -m benchmarks.speed.update_speed --no-d3rlpy algo=...     # ours only (no reference venv)

Builds, for each ``--algos`` entry, the recipe's :class:`~torchrl_dual.recipe.O2ORun` at
``budget=smoke`` with ``--width`` x 2 networks and ``--batch`` transitions per batch
(trailing ``key=value`` arguments are more overrides) and its learner, and samples
``--batches`` batches from its offline replay (``D_offline``; Cal-QL's carries its Monte-
Carlo labels). d3rlpy's IQL and Cal-QL (``reference_learners.D3rlpyLearner``, the
learners of ``reference_d3rlpy.py``) run in a worker process in the reference venv
(``.venv-reference``, built by ``reference_d3rlpy.py --setup``) on the same batches,
saved to a file. After ``--warmup`` updates each, rounds alternate between every update
(ours and the worker's, one after the other), each timing ``--updates`` updates in CPU
seconds of its own process, one torch thread each, so load from other processes touches
every update alike. Prints the median ms per update and the median over rounds of the
ratios in the same round: ours / d3rlpy's for IQL and Cal-QL, DUAL / IQL (ours).

``--profile N`` then runs ``torch.profiler`` over ``N`` more of each of our updates and
splits its CPU time into GEMMs (``addmm``, ``mm``, ``bmm``, ...), the optimizer steps
(``Optimizer.step``), the soft target updates, other ATen kernels, and the rest: Python,
TensorDict and dispatcher overhead between the kernels.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.learning.reference_d3rlpy import venv_python
from benchmarks.provenance import write_json

REPO = Path(__file__).resolve().parents[2]

GEMMS = ("aten::addmm", "aten::mm", "aten::bmm", "aten::baddbmm", "aten::linear_backward")
REFERENCES = ("iql", "calql")


def make_run(algo: str, args: argparse.Namespace, out: Path, learner=None):
    """The recipe's run of ``algo`` at the benchmark's sizes (``learner`` replaces its own
    learner class: d3rlpy's)."""
    from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, O2ORun, compose_checked

    overrides = [
        "budget=smoke",
        f"budget.network_width={args.width}",
        f"budget.batch_size={args.batch}",
        "progress=false",
        "num_threads=1",
        f"algo={algo}",
        f"output_dir={out}",
        *args.overrides,
    ]
    cfg = compose_checked(CONFIG_DIR, overrides)
    return O2ORun(cfg, learner or ALGORITHMS[algo].learner)


def cpu_ms(update, batches: list, n: int, start: int) -> float:
    """CPU ms per update of ``n`` updates on ``batches`` from index ``start`` (cyclic)."""
    begin = time.process_time()
    for i in range(start, start + n):
        update(batches[i % len(batches)])
    return 1000 * (time.process_time() - begin) / n


# ---------------------------------------------------------------- the d3rlpy worker
def worker(args: argparse.Namespace) -> None:
    """In the reference venv: d3rlpy's learners on the saved batches; on each stdin line
    ``algo n start`` times ``n`` updates and prints the CPU ms per update."""
    from benchmarks.learning.reference_learners import D3rlpyLearner

    torch.set_num_threads(1)
    batches = torch.load(args.worker, weights_only=False)
    learners = {}
    with tempfile.TemporaryDirectory() as tmp:
        for algo in batches:
            learners[algo] = make_run(algo, args, Path(tmp) / algo, D3rlpyLearner).learner
        print("@ready", flush=True)
        for line in sys.stdin:
            algo, n, start = line.split()
            ms = cpu_ms(learners[algo].update, batches[algo], int(n), int(start))
            print(f"@{ms!r}", flush=True)


class Worker:
    """The d3rlpy worker process, one request at a time."""

    def __init__(self, args: argparse.Namespace, path: Path) -> None:
        cmd = [str(venv_python()), "-m", "benchmarks.speed.update_speed", "--worker", str(path)]
        cmd += ["--width", str(args.width), "--batch", str(args.batch), *args.overrides]
        self.proc = subprocess.Popen(
            cmd, cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        self.reply()

    def reply(self) -> str:
        """The worker's next ``@`` line (its runs' log lines go to stdout too)."""
        for line in self.proc.stdout:
            if line.startswith("@"):
                return line[1:].strip()
        raise SystemExit("error: the d3rlpy worker stopped (its stderr is above)")

    def time(self, algo: str, n: int, start: int) -> float:
        self.proc.stdin.write(f"{algo} {n} {start}\n")
        self.proc.stdin.flush()
        return float(self.reply())

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def reference_venv_ready() -> bool:
    python = venv_python()
    return python.exists() and subprocess.run([str(python), "-c", "import d3rlpy"]).returncode == 0


# ---------------------------------------------------------------- the profile
def profile(update, batches: list, n: int) -> dict[str, float]:
    """ms per update of ``torch.profiler``'s wall time, split as the module docstring says."""
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    begin = (
        time.perf_counter()
    )  # wall time, as the profiler's (CPU time undercounts a loaded machine's)
    with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
        for i in range(n):
            update(batches[i % len(batches)])
    total = 1000 * (time.perf_counter() - begin) / n
    events = prof.key_averages()
    aten_self = sum(e.self_cpu_time_total for e in events if e.key.startswith("aten::"))
    gemm = sum(e.self_cpu_time_total for e in events if e.key in GEMMS)
    optim = sum(e.cpu_time_total for e in events if e.key.startswith("Optimizer.step#"))
    optim_ops = sum(
        e.cpu_time_total
        for e in events
        if e.key.startswith("Optimizer.zero_grad#") or e.key.startswith("Optimizer.step#")
    )
    top = sorted(
        (e for e in events if e.key.startswith("aten::")),
        key=lambda e: e.self_cpu_time_total,
        reverse=True,
    )[:8]
    per = 1e-3 / n  # us over n updates -> ms per update
    return {
        "wall_ms_profiled": total,
        "aten_kernels_ms": aten_self * per,
        "gemm_ms": gemm * per,
        "optimizer_ms": optim_ops * per,
        "optimizer_step_ms": optim * per,
        "other_kernels_ms": (aten_self - gemm) * per,
        "top_kernels_ms": {e.key: e.self_cpu_time_total * per for e in top},
    }


# ---------------------------------------------------------------- main
def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algos", nargs="+", default=["iql", "calql", "dual"])
    parser.add_argument("--width", type=int, default=256)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--batches", type=int, default=20)
    parser.add_argument("--warmup", type=int, default=20)
    parser.add_argument("--updates", type=int, default=50, help="per round and update")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--profile", type=int, default=0, metavar="N")
    parser.add_argument("--no-d3rlpy", action="store_true")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    parser.add_argument("overrides", nargs="*", help="more recipe overrides (key=value)")
    args = parser.parse_args(argv)
    if args.worker is not None:
        worker(args)
        return {}
    torch.set_num_threads(1)
    with_d3rlpy = not args.no_d3rlpy and reference_venv_ready()
    if not args.no_d3rlpy and not with_d3rlpy:
        print("no reference venv with d3rlpy (reference_d3rlpy.py --setup): ours only")
    machine = {
        "cpu": platform.processor() or platform.machine(),
        "cores": os.cpu_count(),
        "threads": 1,
        "load_average": os.getloadavg(),
        "torch": torch.__version__,
    }
    try:
        machine["cpu"] = next(
            line.split(":", 1)[1].strip()
            for line in Path("/proc/cpuinfo").read_text().splitlines()
            if line.startswith("model name")
        )
    except (OSError, StopIteration):
        pass
    print(
        f"{machine['cpu']}, {machine['cores']} cores, one torch thread, load "
        f"{machine['load_average'][0]:.2f} | {args.width} x 2, batch {args.batch}, "
        f"{args.rounds} rounds of {args.updates} updates"
    )
    times: dict[str, list[float]] = {}
    prof: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        learners, batches = {}, {}
        for algo in args.algos:
            run = make_run(algo, args, Path(tmp) / algo)
            learners[algo] = run.learner.update
            torch.manual_seed(0)
            batches[algo] = [run.offline_buffer.sample().clone() for _ in range(args.batches)]
        updates = {algo: learners[algo] for algo in args.algos}
        ref = None
        if with_d3rlpy:
            path = Path(tmp) / "batches.pt"
            torch.save({a: batches[a] for a in args.algos if a in REFERENCES}, path)
            if any(a in REFERENCES for a in args.algos):
                ref = Worker(args, path)
        try:
            names = list(updates)
            if ref is not None:
                names += [f"{a}_d3rlpy" for a in args.algos if a in REFERENCES]

            def timed(name: str, n: int, start: int) -> float:
                if name.endswith("_d3rlpy"):
                    return ref.time(name.removesuffix("_d3rlpy"), n, start)
                return cpu_ms(updates[name], batches[name], n, start)

            for name in names:  # warm-up: optimizer state, allocator, lazy modules
                timed(name, args.warmup, 0)
            for r in range(args.rounds):
                for name in names if r % 2 == 0 else names[::-1]:
                    times.setdefault(name, []).append(
                        timed(name, args.updates, args.warmup + r * args.updates)
                    )
        finally:
            if ref is not None:
                ref.close()
        for algo in args.algos if args.profile else ():
            prof[algo] = profile(updates[algo], batches[algo], args.profile)

    def ratios(a: str, b: str) -> list[float]:
        return [x / y for x, y in zip(times[a], times[b], strict=True)]

    result: dict = {"machine": machine, "args": {k: str(v) for k, v in vars(args).items()}}
    result["ms_per_update"] = {k: statistics.median(v) for k, v in times.items()}
    result["ms_per_update_all"] = times
    pairs = [(a, f"{a}_d3rlpy") for a in REFERENCES if f"{a}_d3rlpy" in times]
    if "dual" in times and "iql" in times:
        pairs.append(("dual", "iql"))
    result["ratios"] = {f"{a}/{b}": statistics.median(ratios(a, b)) for a, b in pairs}
    result["ratios_all"] = {f"{a}/{b}": ratios(a, b) for a, b in pairs}
    print("| update | CPU ms/update (median) | min - max |")
    print("|---|---:|---:|")
    for name, values in times.items():
        print(
            f"| {name} | {statistics.median(values):.2f} | {min(values):.2f} - {max(values):.2f} |"
        )
    for key, values in result["ratios_all"].items():
        print(f"{key}: {statistics.median(values):.3f} ({min(values):.3f} - {max(values):.3f})")
    if prof:
        result["profile"] = prof
        print("\n| update | profiled wall ms | GEMMs | optimizer | other kernels | overhead |")
        print("|---|---:|---:|---:|---:|---:|")
        for algo, p in prof.items():
            rest = p["wall_ms_profiled"] - p["aten_kernels_ms"]
            print(
                f"| {algo} | {p['wall_ms_profiled']:.2f} | {p['gemm_ms']:.2f} | "
                f"{p['optimizer_ms']:.2f} | {p['other_kernels_ms']:.2f} | {rest:.2f} |"
            )
            tops = ", ".join(f"{k} {v:.2f}" for k, v in p["top_kernels_ms"].items())
            print(f"  {algo} top kernels (self ms): {tops}")
    if args.json is not None:
        write_json(args.json, result, indent=2)
    return result


if __name__ == "__main__":
    main()
