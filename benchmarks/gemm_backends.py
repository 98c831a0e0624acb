"""Where the actor+critic update's time goes: matrix products in MKL, against oneDNN.

Issue #9 asks for the recipe's offline actor+critic update (``budget=default``: batch 256,
width 256) to run at least 2× faster without changing what it computes. This script
answers how far any rewrite can get on the machine it runs on:

1. **Trace**: a child process builds the recipe's learner (``--algo``, default ``dual``)
   on a locally generated PointMaze U-maze data set and runs ``--updates`` updates with
   ``MKL_VERBOSE=1``; every single-precision GEMM call is read back from MKL's log with
   its shape and time. Their sum against the update's time is the GEMM share, and
   ``1 / (1 − share)`` the speed-up that even free GEMMs would give (Amdahl).
   MKL's header line names the code path it dispatched to on this CPU.
2. **Backends**: each traced GEMM shape is timed with MKL (``torch.mm`` / ``torch.bmm``,
   what PyTorch's CPU wheels call) and with oneDNN (``torch._C._nn.mkldnn_linear`` on
   oneDNN tensors, conversions included), rounds alternating, and the ratio of medians
   printed; both compute the same float32 products (results agree to float32 rounding,
   checked first).
   Every shape is timed as ``x [n, k] @ w[m, k].T`` whatever its transposes.
3. **Projection**: the update's time with each timed GEMM on the faster of the two
   backends, and its speed-up.

Single-threaded (``--threads``), like the learning suite's runs::

    python benchmarks/gemm_backends.py
    python benchmarks/gemm_backends.py --algo iql --updates 30 --json gemm.json

The trace needs PyTorch built with MKL (the x86 wheels); the numbers are this machine's.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch

REPO = Path(__file__).resolve().parents[1]
GEMM_LINE = re.compile(r"^MKL_VERBOSE (SGEMM_BATCH|SGEMM)\((.*)\) ([\d.]+)(ns|us|ms|s) CNR")
UNIT_MS = {"ns": 1e-6, "us": 1e-3, "ms": 1.0, "s": 1e3}


# ---------------------------------------------------------------------- the trace
def child(algo: str, updates: int, data_dir: str) -> None:
    """Runs in the traced process: builds the learner, warms up, then brackets
    ``updates`` updates with markers on stdout (MKL's log goes there too)."""
    from torchrl_dual.recipe import O2ORun, compose_checked
    from torchrl_dual.recipe.algorithms import ALGORITHMS

    torch.set_num_threads(int(os.environ.get("GEMM_THREADS", "1")))
    cfg = compose_checked(
        REPO / "recipes" / "config",
        [
            "budget=default",
            f"algo={algo}",
            "budget.dataset_transitions=20000",
            f"output_dir={data_dir}/run",
            f"data_cache_dir={data_dir}/data",
            "progress=false",
            "num_threads=1",
        ],
    )
    run = O2ORun(cfg, ALGORITHMS[algo].learner)
    batches = [run.offline_buffer.sample() for _ in range(updates + 5)]
    for batch in batches[:5]:
        run.learner.update(batch)
    print("GEMM_TRACE_BEGIN", flush=True)
    start = time.process_time()
    for batch in batches[5:]:
        run.learner.update(batch)
    ms = 1000 * (time.process_time() - start) / updates
    print(f"GEMM_TRACE_END {ms}", flush=True)


def trace(algo: str, updates: int, threads: int) -> dict:
    """MKL's log of ``updates`` updates: ms per update, GEMM ms per update by shape."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "MKL_VERBOSE": "1",
            "OMP_NUM_THREADS": str(threads),
            "GEMM_THREADS": str(threads),
            "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]),
        }
        cmd = [sys.executable, __file__, "--child", algo, str(updates), tmp]
        proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"the traced run failed:\n{proc.stderr[-3000:]}")
    return parse_trace(proc.stdout.splitlines(), updates)


def parse_trace(lines: list[str], updates: int) -> dict:
    """The child's stdout: MKL's header, ms per update between the markers, and the
    GEMM ms per update by column-major shape (``"TN 256x256x64"``; ``"batched"`` for
    ``SGEMM_BATCH``, whose log line carries pointers only)."""
    header = next((line for line in lines if line.startswith("MKL_VERBOSE oneMKL")), "")
    begin = lines.index("GEMM_TRACE_BEGIN")
    end = next(i for i, line in enumerate(lines) if line.startswith("GEMM_TRACE_END"))
    by_shape: dict[str, float] = defaultdict(float)
    calls = 0
    for line in lines[begin + 1 : end]:
        match = GEMM_LINE.match(line)
        if match is None:
            continue
        kind, args, value, unit = match.groups()
        calls += 1
        if kind == "SGEMM":  # column-major (transa, transb, m, n, k, ...)
            transa, transb, m, n, k = args.split(",")[:5]
            shape = f"{transa}{transb} {m}x{n}x{k}"
        else:
            shape = "batched"
        by_shape[shape] += float(value) * UNIT_MS[unit] / updates
    return {
        "mkl_header": header.replace("MKL_VERBOSE ", ""),
        "ms_per_update": float(lines[end].split()[1]),
        "gemm_calls_per_update": calls / updates,
        "gemm_ms_by_shape": dict(sorted(by_shape.items(), key=lambda kv: -kv[1])),
    }


# ---------------------------------------------------------------------- the backends
def median_us(fn, reps: int) -> float:
    for _ in range(5):
        fn()
    start = time.perf_counter()
    for _ in range(reps):
        fn()
    return 1e6 * (time.perf_counter() - start) / reps


def shape_operands(shape: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Row-major ``x [n, k]`` and ``w [m, k]`` for the product ``x @ w.T [n, m]`` that a
    column-major ``SGEMM(m, n, k)`` log line computes, up to the transposes."""
    m, n, k = (int(v) for v in shape.split()[1].split("x"))
    gen = torch.Generator().manual_seed(0)
    return torch.randn(n, k, generator=gen), torch.randn(m, k, generator=gen)


def compare_backends(shapes: list[str], rounds: int, reps: int) -> dict[str, dict]:
    """MKL against oneDNN on each shape (the batched GEMMs as the twin critic's
    ``[2, 256, 256] @ [2, 256, 256]``), rounds alternating; medians and ratio."""
    out = {}
    for shape in shapes:
        if shape == "batched":
            gen = torch.Generator().manual_seed(0)
            x, w = torch.randn(2, 256, 256, generator=gen), torch.randn(2, 256, 256, generator=gen)
            wm = [w[i].to_mkldnn() for i in range(2)]

            def mkl(x=x, w=w):
                return torch.bmm(x, w.transpose(1, 2))

            def onednn(x=x, wm=wm):
                return torch.stack(
                    [
                        torch._C._nn.mkldnn_linear(x[i].to_mkldnn(), wm[i], None).to_dense()
                        for i in range(2)
                    ]
                )
        else:
            x, w = shape_operands(shape)
            wm = w.to_mkldnn()

            def mkl(x=x, w=w):
                return x @ w.T

            def onednn(x=x, wm=wm):
                return torch._C._nn.mkldnn_linear(x.to_mkldnn(), wm, None).to_dense()

        reference = mkl().double()
        scale = reference.abs().max().item()
        error = (onednn().double() - reference).abs().max().item() / scale
        if error > 1e-5:
            raise RuntimeError(f"oneDNN and MKL disagree on {shape}: relative error {error:.1e}")
        times: dict[str, list[float]] = {"mkl": [], "onednn": []}
        for _ in range(rounds):
            times["mkl"].append(median_us(mkl, reps))
            times["onednn"].append(median_us(onednn, reps))
        mkl_us, onednn_us = (statistics.median(v) for v in times.values())
        out[shape] = {
            "mkl_us": mkl_us,
            "onednn_us": onednn_us,
            "ratio": mkl_us / onednn_us,
            "max_relative_difference": error,
        }
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        child(argv[1], int(argv[2]), argv[3])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--algo", default="dual", help="the recipe's algo= (default dual)")
    parser.add_argument("--updates", type=int, default=20, help="traced updates")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=7, help="alternating rounds per shape")
    parser.add_argument("--reps", type=int, default=50, help="calls per round")
    parser.add_argument(
        "--min-share",
        type=float,
        default=0.01,
        help="time shapes holding at least this share of the GEMM time",
    )
    parser.add_argument("--json", type=Path, help="write the figures here")
    args = parser.parse_args(argv)
    if not torch.backends.mkl.is_available() or not torch.backends.mkldnn.is_available():
        parser.error("needs PyTorch built with MKL and oneDNN (the x86 CPU wheels)")
    torch.set_num_threads(args.threads)

    traced = trace(args.algo, args.updates, args.threads)
    update_ms = traced["ms_per_update"]
    gemm = traced["gemm_ms_by_shape"]
    gemm_ms = sum(gemm.values())
    print(f"MKL: {traced['mkl_header']}")
    print(
        f"{args.algo} update (MKL_VERBOSE on): {update_ms:.1f} ms, "
        f"{traced['gemm_calls_per_update']:.0f} GEMM calls = {gemm_ms:.1f} ms "
        f"({100 * gemm_ms / update_ms:.0f} %); free GEMMs would give at most "
        f"{update_ms / (update_ms - gemm_ms):.2f}x"
    )
    timed = [s for s, ms in gemm.items() if ms >= args.min_share * gemm_ms]
    backends = compare_backends(timed, args.rounds, args.reps)
    print(
        f"\n{'GEMM (column-major)':<24}{'ms/update':>10}{'MKL us':>9}{'oneDNN us':>11}{'ratio':>8}"
    )
    projected_gemm = gemm_ms
    for shape in timed:
        b = backends[shape]
        # a dispatcher would keep the shapes where oneDNN is slower on MKL
        projected_gemm -= gemm[shape] * (1 - 1 / max(b["ratio"], 1.0))
        print(
            f"{shape:<24}{gemm[shape]:>10.2f}{b['mkl_us']:>9.0f}{b['onednn_us']:>11.0f}"
            f"{b['ratio']:>7.2f}x"
        )
    projected = update_ms - gemm_ms + projected_gemm
    print(
        f"\nprojected update with each timed GEMM on the faster backend: {projected:.1f} ms "
        f"({update_ms / projected:.2f}x; the issue's target is 2x)"
    )
    if args.json:
        result = {
            **traced,
            "algo": args.algo,
            "threads": args.threads,
            "backends": backends,
            "projected_ms_per_update": projected,
            "projected_speedup": update_ms / projected,
            "torch": torch.__version__,
            "date": time.strftime("%Y-%m-%d"),
        }
        args.json.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
