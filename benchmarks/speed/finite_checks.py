"""What DUAL's NaN/inf checks cost: one ``DUALLoss`` update with ``check_finite`` on, then
off, alternating in one process (the two share the machine's load of each moment).

The update is the recipe's (``CriticActorStepper`` on ``DUALLoss``: IQL's critic step,
the soft update, then Eq. 7's actor step) at ``budget=paper``'s sizes
(:class:`~benchmarks.speed.gpu_workloads.Sizes`: the distilled 256-wide planner actor,
batch 256), on one CPU thread. The checks are 5 host reads per update (the two critic
terms, the actor's two inputs, Eq. 7's weights). Prints the median milliseconds of each
side and the ratio of the medians::

    python -m benchmarks.speed.finite_checks --updates 50 --rounds 5 --json out.json
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from benchmarks.provenance import write_json
from benchmarks.speed.gpu_workloads import Sizes, build_actor_critic


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--updates", type=int, default=50, help="updates per round and side")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--tiny", action="store_true", help="tiny networks (the test's)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    from benchmarks.speed.gpu_workloads import TINY

    update, batch = build_actor_critic(TINY if args.tiny else Sizes(), "cpu", capturable=False)
    loss = update.__self__.loss
    times: dict[bool, list[float]] = {True: [], False: []}
    for _ in range(args.rounds):
        for checks in (True, False):
            loss.check_finite = checks
            update(batch)  # warm
            start = time.perf_counter()
            for _ in range(args.updates):
                update(batch)
            times[checks].append(1e3 * (time.perf_counter() - start) / args.updates)
    on, off = statistics.median(times[True]), statistics.median(times[False])
    report = {
        "updates": args.updates,
        "rounds": args.rounds,
        "sizes": "tiny" if args.tiny else "paper",
        "ms_per_update_checks_on": times[True],
        "ms_per_update_checks_off": times[False],
        "median_on_ms": on,
        "median_off_ms": off,
        "ratio_of_medians_on_over_off": on / off,
    }
    print(f"checks on {on:.2f} ms, off {off:.2f} ms per update: on / off {on / off:.3f} "
          "(ratio of the medians)")  # fmt: skip
    if args.json:
        write_json(args.json, report)
    return report


if __name__ == "__main__":
    main()
