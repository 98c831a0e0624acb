"""DUAL through TorchRL's ``Trainer`` against the recipe, same data, seed and budget.

Issue 42's check of ``recipes/torchrl_trainer.py``: each seed trains DUAL through
``Trainer.train()`` (the recipe's builders, TorchRL's loop, hooks and replay buffer) on a
learning-suite cell's overrides, evaluates after the offline stages and every
``budget.eval_every`` frames with the recipe's evaluator, and is set next to the suite's
``dual`` run of the same cell and seed (``benchmarks/results/<budget>/<cell>/dual``):
paired differences of the offline and final normalized scores with their 95 % t interval
and a TOST verdict against ±10 points (``benchmarks.learning.stats``).

    python -m benchmarks.studies.trainer_vs_recipe --seeds 5 6 7 --json out.json
    python -m benchmarks.studies.trainer_vs_recipe --report out.json   # table only

The runs write a JSON per invocation (``--json``), so seeds can run in separate processes
and be reported together (``--report a.json b.json``).
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

from benchmarks.learning.backends import machine
from benchmarks.learning.cells import CELLS
from benchmarks.learning.stats import equivalence, fmt, t_interval
from benchmarks.provenance import write_json

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "recipes" / "torchrl_trainer.py"
RESULTS = REPO / "benchmarks" / "results"


def load_trainer_script():
    """``recipes/torchrl_trainer.py`` as a module (it is a script, not a package); its
    test loads it through here too."""
    spec = importlib.util.spec_from_file_location("torchrl_trainer", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclasses resolve their annotations there
    spec.loader.exec_module(module)
    return module


def run_seed(cell: str, budget: str, seed: int, output_dir: Path) -> dict:
    """One seed through the trainer path: its scores after the offline stages and at each
    evaluation, and its CPU seconds."""
    script = load_trainer_script()
    argv = [
        *CELLS[cell].overrides,
        "algo=dual",
        f"budget={budget}",
        f"seed={seed}",
        "progress=false",
        "num_threads=1",
        f"output_dir={output_dir}",
        "trainer.progress_bar=false",
    ]
    start = time.process_time()
    trainer = script.build_trainer(*script.compose_configs(argv))
    evaluation = trainer._modules["normalized_score"]
    offline: dict[str, float] = {}
    # after the offline stages (registered first at setup): the score Alg. 1 starts from
    trainer.register_op("setup", lambda: offline.update(evaluation.evaluate()))
    trainer.train()
    scores = [float(s) for s in trainer._log_dict["eval/normalized_score"]]
    return {
        "seed": seed,
        "offline_score": float(offline["normalized_score"]),
        "scores": scores,
        "final_score": scores[-1],
        "frames": int(trainer.collected_frames),
        "cpu_seconds": time.process_time() - start,
    }


def recipe_result(budget: str, cell: str, seed: int) -> dict | None:
    path = RESULTS / budget / cell / "dual" / f"seed{seed}.json"
    return json.loads(path.read_text()) if path.exists() else None


def report(records: list[dict], budget: str, cell: str) -> str:
    """The per-seed table and the paired differences trainer − recipe."""
    lines = [
        f"DUAL on `{cell}` (`budget={budget}`): TorchRL's Trainer against the recipe's run",
        "",
        "| seed | trainer offline | recipe offline | trainer final | recipe final |",
        "|---:|---:|---:|---:|---:|",
    ]
    diffs: dict[str, list[float]] = {"offline": [], "final": []}
    for rec in sorted(records, key=lambda r: r["seed"]):
        ref = recipe_result(budget, cell, rec["seed"])
        ref_off = ref["offline_score"] if ref else float("nan")
        ref_fin = ref["final_score"] if ref else float("nan")
        lines.append(
            f"| {rec['seed']} | {rec['offline_score']:.1f} | {ref_off:.1f} | "
            f"{rec['final_score']:.1f} | {ref_fin:.1f} |"
        )
        if ref:
            diffs["offline"].append(rec["offline_score"] - ref_off)
            diffs["final"].append(rec["final_score"] - ref_fin)
    lines.append("")
    for name, values in diffs.items():
        if values:
            lines.append(
                f"{name}: trainer − recipe {fmt(t_interval(values))} (n = {len(values)}, "
                f"95 % t); equivalent within ±10: {equivalence(values).text()}"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cell", default="umaze_fresh", choices=sorted(CELLS))
    parser.add_argument("--budget", default="default")
    parser.add_argument("--seeds", type=int, nargs="*", default=[5, 6, 7])
    parser.add_argument("--json", type=Path, help="write this invocation's runs here")
    parser.add_argument("--report", type=Path, nargs="+", help="report these JSONs, run nothing")
    args = parser.parse_args(argv)
    if args.report:
        loaded = [json.loads(p.read_text()) for p in args.report]
        records = [r for d in loaded for r in d["runs"]]
        print(report(records, loaded[0]["budget"], loaded[0]["cell"]))
        return
    torch.set_num_threads(1)
    records = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as tmp:
            records.append(run_seed(args.cell, args.budget, seed, Path(tmp)))
        print(f"seed {seed}: {records[-1]}", flush=True)
    out = {
        "cell": args.cell,
        "budget": args.budget,
        "runs": records,
        "machine": machine(),
        "date": datetime.date.today().isoformat(),
        "command": "python -m benchmarks.studies.trainer_vs_recipe "
        + " ".join(argv or sys.argv[1:]),
    }
    if args.json:
        write_json(args.json, out, indent=1)
    print(report(records, args.budget, args.cell))


if __name__ == "__main__":
    main()
