"""Summarise recipe runs over seeds: normalized scores (mean ± std) and a curve PNG.

    python -m benchmarks.studies.o2o_seeds outputs/pointmaze_umaze/dual/default/seed0 \\
        outputs/pointmaze_umaze/dual/default/seed1 outputs/pointmaze_umaze/dual/default/seed2 \\
        --png docs/figures/pointmaze_umaze_default.png

Reads each run's ``checkpoint.pt`` (its evaluation history) and prints a markdown table
of the offline score, the final online score and every evaluation point.
A run directory is the recipe's ``output_dir``, by default
``outputs/<env>/<algo>/<budget>/seed<k>``.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import torch


def load_history(run_dir: Path) -> list[dict]:
    payload = torch.load(run_dir / "checkpoint.pt", map_location="cpu", weights_only=False)
    return payload["state"]["history"]


def mean_std(values: list[float]) -> str:
    std = statistics.stdev(values) if len(values) > 1 else 0.0
    return f"{statistics.mean(values):.1f} ± {std:.1f}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("runs", nargs="+", type=Path, help="output_dir of each seed")
    parser.add_argument("--png", type=Path, help="write the learning curves here")
    args = parser.parse_args(argv)
    histories = [load_history(run) for run in args.runs]
    frames = sorted({h["frames"] for history in histories for h in history})
    print(f"| frames | normalized score (mean ± std over {len(histories)} seeds) | per seed |")
    print("|---:|---|---|")
    for frame in frames:
        scores = [h["normalized_score"] for hist in histories for h in hist if h["frames"] == frame]
        per_seed = ", ".join(f"{s:.1f}" for s in scores)
        print(f"| {frame} | {mean_std(scores)} | {per_seed} |")
    offline = [hist[0]["normalized_score"] for hist in histories]
    final = [hist[-1]["normalized_score"] for hist in histories]
    print(f"\noffline: {mean_std(offline)}; end of online phase: {mean_std(final)}")
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        for run, hist in zip(args.runs, histories, strict=True):
            xs = [h["frames"] for h in hist]
            ax.plot(
                xs, [h["normalized_score"] for h in hist], alpha=0.35, marker=".", label=run.name
            )
        means = [
            statistics.mean(
                [h["normalized_score"] for hist in histories for h in hist if h["frames"] == f]
            )
            for f in frames
        ]
        ax.plot(frames, means, color="black", linewidth=2, label="mean")
        ax.set_xlabel("online environment frames (0 = end of the offline phase)")
        ax.set_ylabel("normalized score")
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.png, dpi=120)
        print(f"curves: {args.png}")


if __name__ == "__main__":
    main()
