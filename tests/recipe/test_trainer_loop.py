"""The recipe's run on TorchRL's ``Trainer`` (``recipe/o2o/loop.py``).

The trainer is TorchRL's own class with the recipe's ops at the stages the module's
table names; it runs as many updates per collected batch as the fractional
update-to-data credit allows; its collector starts a new TorchRL collector at each
periodic checkpoint; its progress bar counts the online frames, from a resumed run's
frames on.
"""

from __future__ import annotations

import contextlib
import io

from recipe_runner import TINY
from torchrl.collectors import Collector
from torchrl.trainers import Trainer

from torchrl_dual.recipe import CONFIG_DIR, IQLLearner, O2ORun, compose_checked, run_o2o
from torchrl_dual.recipe.o2o.loop import CutPoints, make_trainer
from torchrl_dual.recipe.o2o.update_step import LearnerUpdates


def _cfg(tmp_path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [
            *TINY,
            "algo=iql",
            f"output_dir={tmp_path / 'run'}",
            f"data_cache_dir={tmp_path}/d",
            *overrides,
        ],
    )


def test_the_run_is_torchrl_s_trainer_with_the_recipe_s_ops_at_their_stages(tmp_path):
    with contextlib.redirect_stdout(io.StringIO()):
        run = O2ORun(_cfg(tmp_path), IQLLearner)
    trainer, phase = make_trainer(run)
    assert type(trainer) is Trainer  # TorchRL's loop, not a subclass of ours
    assert isinstance(trainer.collector, CutPoints)
    assert trainer.optimization_stepper is run.update and isinstance(run.update, LearnerUpdates)
    ops = {
        "setup": trainer._setup_ops,
        "batch_process": trainer._batch_process_ops,
        "process_optim_batch": trainer._process_optim_batch_ops,
        "post_steps": trainer._post_steps_ops,
        "post_steps_log": trainer._post_steps_log_ops,
        "shutdown": trainer._shutdown_ops,
    }
    names = {stage: [op.__name__ for op, _ in registered] for stage, registered in ops.items()}
    assert names == {
        "setup": ["offline"],
        "batch_process": ["store"],
        "process_optim_batch": ["sample"],
        "post_steps": ["after_updates"],
        "post_steps_log": ["log_evaluate_checkpoint"],
        "shutdown": ["finish"],
    }


def test_each_batch_gets_the_updates_its_fractional_credit_allows(tmp_path):
    # 50 frames per batch at 0.3 updates per frame: 15 updates a batch, no remainder;
    # at 0.25 over 4 batches of 25: 6.25 a batch, so 6, 6, 6 and 7 (the credit carries)
    cases = {("0.3", "50"): [15, 15], ("0.25", "25"): [6, 6, 6, 7]}
    for (utd, per_batch), expected in cases.items():
        out = tmp_path / f"{utd}_{per_batch}"
        cfg = _cfg(out, f"online.utd_ratio={utd}", f"budget.frames_per_batch={per_batch}")
        per_batch_updates: list[int] = []
        with contextlib.redirect_stdout(io.StringIO()):
            run = O2ORun(cfg, IQLLearner)
            trainer, _ = make_trainer(run)
            _count_updates(trainer, run, per_batch_updates)
            trainer.train()
        assert per_batch_updates == expected, (utd, per_batch)
        assert run.updates == 4 + sum(expected)  # budget.offline_updates=4 before them
        assert run.frames == 100 and trainer.collected_frames == 100


def _count_updates(trainer, run, counts: list[int]) -> None:
    """Registers ops appending the updates of each collected batch to ``counts``."""
    before = [0]

    def start(batch) -> None:
        before[0] = run.updates

    def count() -> None:
        counts.append(run.updates - before[0])

    trainer.register_op("batch_process", start)
    trainer.register_op("post_steps", count)


def test_a_new_collector_starts_at_each_checkpoint(tmp_path):
    # 100 frames, batches of 25, a checkpoint every 50: two stretches of two batches
    cfg = _cfg(tmp_path, "budget.frames_per_batch=25", "budget.checkpoint_every=50")
    started: list[int] = []
    with contextlib.redirect_stdout(io.StringIO()):
        run = O2ORun(cfg, IQLLearner)
        make = run.collector

        def collector():
            started.append(run.frames)
            made = make()
            assert isinstance(made, Collector)
            return made

        run.collector = collector
        trainer, _ = make_trainer(run)
        trainer.train()
    assert started == [0, 50]
    assert trainer.collector.current is None  # the last one was stopped before the summary


def test_the_progress_bar_counts_online_frames_from_where_a_resumed_run_stands(tmp_path, capsys):
    overrides = [*TINY, "algo=iql", "progress=true", f"output_dir={tmp_path / 'run'}"]
    overrides.append(f"data_cache_dir={tmp_path}/d")
    run_o2o(compose_checked(CONFIG_DIR, [*overrides, "interrupt_at_frames=50"]), IQLLearner)
    capsys.readouterr()
    resumed = run_o2o(compose_checked(CONFIG_DIR, [*overrides, "resume=true"]), IQLLearner)
    err = capsys.readouterr().err
    assert resumed.frames == 100
    assert "50/100" in err and "100/100" in err and " 0/100" not in err
