"""Which learning-suite runs found reward online: per run, the collected batches that hold
any reward, the first frame at which one did, and the evaluations with a positive return.

On a task whose reward lies where the offline data never go (``medium_explore``), whether
the exploration reaches it at all is the first thing to know, before any score: the
normalized score moves only once the policy has learnt to go there. The figures come from
each run's JSON under ``benchmarks/results``: its evaluations, and the reward per step of
each collected batch (``online_signals``, in runs started since 2026-12-05 06:06 UTC); for older
runs the batch rewards are read from the run's own CSV log
(``logs/*/scalars/online/reward_per_step.csv`` under ``--runs``, not committed).

    python -m benchmarks.studies.online_reward --cell medium_explore
    python -m benchmarks.studies.online_reward --cell medium_explore --json out.json
    python -m benchmarks.studies.online_reward --cell medium_explore_v2 --against dual_no_uq

``--against`` adds, for every other variant, the exact McNemar test of "found reward"
paired by seed against the named variant: the discordant seeds each way and the one-sided
p-value that the variant finds reward no more often than the reference.
"""

from __future__ import annotations

import argparse
import csv
import json
from math import comb
from pathlib import Path

from benchmarks.provenance import write_json

REPO = Path(__file__).resolve().parents[2]


def reward_batches(run_dir: Path, result: dict) -> list[tuple[int, float]]:
    """``(frames, reward per step)`` of each collected batch of a run: from its result
    JSON when it records them for every batch, else from the CSV log in its ``run_dir``
    (a run resumed across the change records only its later batches)."""
    recorded = result.get("online_signals") or []
    if recorded and all("reward_per_step" in s for s in recorded):
        return [(s["frames"], s["reward_per_step"]) for s in recorded]
    files = sorted(run_dir.glob("logs/*/scalars/online/reward_per_step.csv"))
    if not files:
        raise FileNotFoundError(f"no online/reward_per_step.csv under {run_dir}/logs")
    with files[0].open() as handle:
        return [(int(float(row[0])), float(row[1])) for row in csv.reader(handle) if row]


def run_record(run_dir: Path, summary: dict) -> dict:
    """What one run found: batches with reward, the first such frame, positive evaluations."""
    batches = reward_batches(run_dir, summary)
    found = [frames for frames, reward in batches if reward > 0]
    online = [h for h in summary["history"] if h["label"] == "online"]
    return {
        "batches": len(batches),
        "batches_with_reward": len(found),
        "first_reward_frames": found[0] if found else None,
        "evaluations_with_return": sum(h["return"] > 0 for h in online),
        "evaluations": len(online),
        "final_return": online[-1]["return"] if online else None,
    }


def cell_records(results: Path, runs: Path, cell: str) -> dict[str, dict[int, dict]]:
    """``variant -> seed -> record`` for every run of ``cell`` with a summary JSON."""
    out: dict[str, dict[int, dict]] = {}
    for path in sorted((results / cell).glob("*/seed*.json")):
        summary = json.loads(path.read_text())
        variant, seed = path.parent.name, int(path.stem.removeprefix("seed"))
        out.setdefault(variant, {})[seed] = run_record(runs / cell / variant / path.stem, summary)
    return out


def found_reward(record: dict) -> bool:
    """Whether a run collected any reward online."""
    return record["batches_with_reward"] > 0


def paired_mcnemar(variant: dict[int, dict], reference: dict[int, dict]) -> dict:
    """Exact one-sided McNemar test of "found reward", paired by seed over the seeds both
    variants ran: ``better`` seeds where only ``variant`` found reward, ``worse`` where only
    ``reference`` did, and ``p = P(Binomial(better + worse, 1/2) >= better)``, the chance of
    at least that many wins among the discordant seeds if neither finds reward more often.
    """
    seeds = sorted(set(variant) & set(reference))
    better = sum(found_reward(variant[s]) and not found_reward(reference[s]) for s in seeds)
    worse = sum(found_reward(reference[s]) and not found_reward(variant[s]) for s in seeds)
    discordant = better + worse
    p = sum(comb(discordant, k) for k in range(better, discordant + 1)) / 2**discordant
    return {"seeds": seeds, "better": better, "worse": worse, "p_one_sided": p}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cell", default="medium_explore")
    parser.add_argument("--budget", default="default")
    parser.add_argument("--results", type=Path, default=REPO / "benchmarks" / "results")
    parser.add_argument("--runs", type=Path, default=REPO / "outputs" / "suite")
    parser.add_argument("--json", type=Path, default=None)
    parser.add_argument(
        "--against", default=None, help="reference variant of the paired McNemar test"
    )
    args = parser.parse_args()
    try:
        records = cell_records(args.results / args.budget, args.runs / args.budget, args.cell)
    except FileNotFoundError as err:  # an older run whose JSON lacks the batch rewards
        raise SystemExit(f"error: {err}; pass --runs to the suite's output folder") from None
    print("| variant | seeds that found reward | batches with reward (first frame), by seed |")
    print("|---|---|---|")
    for variant, seeds in records.items():
        found = sum(found_reward(r) for r in seeds.values())
        counts = ", ".join(
            f"{s}: {r['batches_with_reward']}"
            + (f" ({r['first_reward_frames']})" if r["first_reward_frames"] else "")
            for s, r in sorted(seeds.items())
        )
        print(f"| `{variant}` | {found}/{len(seeds)} | {counts} |")
    out: dict = {"cell": args.cell, "runs": records}
    if args.against:
        if args.against not in records:
            raise SystemExit(
                f"error: --against {args.against}: no runs of it in {args.cell} "
                f"(variants with runs: {', '.join(sorted(records))})"
            )
        tests = {
            variant: paired_mcnemar(seeds, records[args.against])
            for variant, seeds in records.items()
            if variant != args.against
        }
        print(
            f"\n| variant | against `{args.against}`: seeds | only it found | only the "
            "reference found | exact one-sided p |"
        )
        print("|---|---:|---:|---:|---:|")
        for variant, t in tests.items():
            print(
                f"| `{variant}` | {len(t['seeds'])} | {t['better']} | {t['worse']} | "
                f"{t['p_one_sided']:.4f} |"
            )
        out["mcnemar"] = {"against": args.against, "tests": tests}
    if args.json:
        write_json(args.json, out, indent=1)


if __name__ == "__main__":
    main()
