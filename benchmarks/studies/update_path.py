"""Which package files one online update of the recipe passes through, in call order.

    python -m benchmarks.studies.update_path                 # DUAL with its IQL critic
    python -m benchmarks.studies.update_path algo=iql critic=iql
    python -m benchmarks.studies.update_path algo=so2   # balanced replay, [k, B] batches

Builds a small Frozen-Lake run (``budget=smoke``, 1000 transitions), then profiles one
call of the trainer's optimization step, ``run.update.step`` (the learner's update on a
batch of D_offline ∪ D_online, its bookkeeping and the replay's own step), after a first
call that builds the optimizers' state; 200 of the data's transitions stand in for
D_online. Each ``torchrl_dual`` file is listed once, where it is first entered; the files
first entered once the learner's update has returned, after its last optimizer step (the
learner's ``after_update``, the replay's own step), are marked.
docs/architecture.md's "Size and shape" table cites the count.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile

from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, O2ORun, compose_checked
from torchrl_dual.recipe.o2o.loop import online_batch


def files_of_one_update(overrides: list[str]) -> tuple[list[str], list[str]]:
    """The ``torchrl_dual`` files one ``run.update.step`` enters, in first-entry order.

    Returns ``(to_the_step, after)``: the files first entered until the learner's update
    returns (its last optimizer step), then those first entered in the bookkeeping after
    it (the learner's ``after_update``, the replay's own step).
    """
    out = tempfile.mkdtemp()
    cfg = compose_checked(
        CONFIG_DIR,
        [
            "env=frozenlake",
            "budget=smoke",
            "progress=false",
            "budget.dataset_transitions=1000",
            f"output_dir={out}/run",
            f"data_cache_dir={out}/data",
            *overrides,
        ],
    )
    with contextlib.redirect_stdout(io.StringIO()):
        run = O2ORun(cfg, ALGORITHMS[cfg.algo].learner)
    # The online phase: the collector's start (SO2's critic takes its online settings)
    # and D_online, where 200 of the data's transitions stand in for collected ones.
    run.learner.collector_started()
    run.replay.extend(run.learner.online_transitions(run.data.transitions[:200].clone()))
    batch = online_batch(run.replay, run.learner.online_batches_per_update, cfg.device)
    run.update.step(None, batch)  # the optimizers' state, lazy modules
    update_code = getattr(run.update.update, "__func__", run.update.update).__code__
    seen: tuple[list[str], list[str]] = ([], [])
    side = seen[0]

    def profile(frame, event, arg):
        nonlocal side
        name = frame.f_code.co_filename
        if event == "return" and frame.f_code is update_code:
            side = seen[1]
        elif event == "call" and "/torchrl_dual/" in name:
            name = name.rsplit("/torchrl_dual/", 1)[1]
            if name not in seen[0] and name not in seen[1]:
                side.append(name)

    sys.setprofile(profile)
    try:
        run.update.step(None, batch)
    finally:
        sys.setprofile(None)
    return seen


def main(argv: list[str] | None = None) -> None:
    """Prints the files and their counts for the overrides in ``argv``."""
    overrides = list(sys.argv[1:] if argv is None else argv) or ["algo=dual"]
    to_step, after = files_of_one_update(overrides)
    recipe = [f for f in to_step if f.startswith("recipe/")]
    print(
        f"{' '.join(overrides)}: {len(to_step)} package files up to the optimizer steps, "
        f"{len(recipe)} of them in recipe/ ({len(to_step) + len(after)} with the "
        "bookkeeping after them)"
    )
    for name in to_step:
        print(f"  {name}")
    for name in after:
        print(f"  {name}   (after the step)")


if __name__ == "__main__":
    main()
