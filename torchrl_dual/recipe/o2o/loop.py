"""One offline-to-online run on TorchRL's :class:`~torchrl.trainers.Trainer`: :func:`run_o2o`.

The run is TorchRL's training loop with the recipe's parts registered as its hooks
(:func:`make_trainer`), in the order Algorithm 1 takes them:

==================================  ============================================================
Trainer stage                       the recipe's op
==================================  ============================================================
``setup``                           the learner's offline stages (l. 1-9; the shared ones
                                    through ``offline_cache``), then the offline evaluation
collector                           :class:`CutPoints`: the ``collector.name`` collector acting
                                    with the exploration policy (l. 11-12), a new one at each
                                    cut point
``batch_process``                   ``run.store``: D_online ← D_online ∪ batch (l. 13), and
                                    ``online.utd_ratio`` update credits per frame
``process_optim_batch``             one sample of D_offline ∪ D_online per credit;
                                    ``StopIteration`` (this batch's updates are done) when
                                    none is left
``optimization_stepper``            ``run.update``, :class:`~torchrl_dual.recipe.o2o.update_step.LearnerUpdates`:
                                    the learner's update (l. 14-16; DUAL: the critic, then
                                    Eq. 7's actor), counted
``post_steps``                      the learner's hook (l. 17, DUAL's Laplace refits), then the
                                    weights' push to the collector's workers
``post_steps_log``                  log, evaluate every ``budget.eval_every`` frames,
                                    checkpoint every ``budget.checkpoint_every`` (a cut point)
``shutdown``                        the last evaluation, the learning curve, ``summary.json``
==================================  ============================================================

What the ``Trainer`` does not do, the smallest piece beside it does
(docs/architecture.md, "The loop"): the checkpoint is the run's own
(:class:`~torchrl_dual.checkpoint.RunCheckpoint`: fingerprinted, atomic, with the
offline stages' mid-stage progress), and every periodic checkpoint is a cut point, where
the next batch comes from a new collector seeded ``seed + 1 + frames``, as after a
resume, so a resumed run continues bitwise as an uninterrupted one would
(docs/recipe.md, "Checkpoint and resume").

Ctrl-C and SIGTERM stop a run alike (``interrupts``): in the offline phase at the end of
an update, whose state the stage's loop saves (``stage_checkpoints``; elsewhere the last
checkpoint stays), in the online phase once the batch in hand is processed, or while the
collector collects; the run saves, prints one line and returns.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase
from torchrl.trainers import Trainer
from tqdm.auto import tqdm

from torchrl_dual.recipe.o2o.collectors import stop_collecting
from torchrl_dual.recipe.o2o.interrupts import held, signals_as_interrupts
from torchrl_dual.recipe.o2o.learner import Learner
from torchrl_dual.recipe.o2o.offline_cache import run_offline_stages
from torchrl_dual.recipe.o2o.plots import online_signals
from torchrl_dual.recipe.o2o.replays import Replay
from torchrl_dual.recipe.o2o.run import O2ORun
from torchrl_dual.recipe.o2o.run_lock import run_directory_lock
from torchrl_dual.recipe.o2o.stage_checkpoints import offline_interruption
from torchrl_dual.recipe.o2o.stage_clock import StageClock
from torchrl_dual.recipe.o2o.update_step import LearnerUpdates
from torchrl_dual.recipe.settings.o2o import COLLECTORS


def online_batch(replay: Replay, k: int, device: torch.device) -> TensorDictBase:
    """One update's sample of D_offline ∪ D_online (``replay``) on ``device``.

    A ``[B]`` batch, or ``[k, B]`` (``k`` batches stacked) for a learner with
    :attr:`~torchrl_dual.recipe.Learner.online_batches_per_update` ``k > 1`` (SO2).
    """
    if k == 1:
        return replay.sample().to(device)
    return torch.stack([replay.sample() for _ in range(k)]).to(device)


def _next_multiple(frames: int, every: int) -> int:
    """The first multiple of ``every`` past ``frames``."""
    return (frames // every + 1) * every


class CutPoints:
    """The trainer's collector: batches of the ``collector.name`` collector, cut at checkpoints.

    A cut point (the start, each periodic checkpoint, a resume) ends the current
    collector and starts a new one (:meth:`O2ORun.collector`: its env seeded by
    ``seed + 1 + frames``, a new episode). The trainer processes each batch inside
    :func:`~torchrl_dual.recipe.o2o.interrupts.held`, so a signal stops the run once
    that batch is processed and checkpointed as due.
    """

    init_random_frames = 0  # read by the Trainer: it updates from the first batch on

    def __init__(self, run: O2ORun) -> None:
        self.run = run
        self.current = None  # the collector of the running stretch
        self.cut = False  # set by the checkpoint: the next batch comes from a new collector

    def __iter__(self) -> Iterator[TensorDictBase]:
        run = self.run
        while run.frames < run.settings.budget.online_frames:
            self.current = run.collector()
            for batch in self.current:
                with held():  # a signal now stops the run after this batch
                    yield batch
                if self.cut:
                    self.cut = False
                    break
            stop_collecting(self.current)
            self.current = None

    def shutdown(self) -> None:
        """Ends the current collector (at the end, on an interrupt or an error).

        Its workers stop; the run's own env (``collector=single``) stays open.
        """
        if self.current is not None:
            stop_collecting(self.current)
            self.current = None


class OnlinePhase:
    """The recipe's ops on the trainer, sharing the online phase's schedule and signals."""

    def __init__(
        self, run: O2ORun, trainer: Trainer, cut_points: CutPoints, updates: LearnerUpdates
    ) -> None:
        self.run, self.trainer, self.cut_points, self.updates = run, trainer, cut_points, updates
        # the weights' way to the collector
        self.push = COLLECTORS[run.settings.collector.name].push
        self.device = torch.device(run.settings.device)
        self.offline_done = False
        self.clock: StageClock | None = None
        self.bar: tqdm | None = None
        self.stats: dict = {}

    def offline(self) -> None:
        """``setup``: the offline stages and the offline evaluation; the online schedule."""
        run, budget = self.run, self.run.settings.budget
        run_offline_stages(run)
        run.stage("offline_eval", lambda: run.evaluate("offline"))
        self.offline_done = True
        self.next_eval = _next_multiple(run.frames, budget.eval_every)
        self.next_save = _next_multiple(run.frames, budget.checkpoint_every)
        self.clock = StageClock(run.stage_seconds, run.stage_cpu_seconds, "online")
        # the online frames' bar, from a resumed run's frames on (TorchRL's starts at 0)
        self.bar = tqdm(
            desc="online frames",
            total=budget.online_frames,
            initial=run.frames,
            disable=not run.settings.progress,
        )

    def store(self, batch: TensorDictBase) -> None:
        """``batch_process``: stores the batch (l. 11-13); ``utd_ratio`` credits per frame."""
        run = self.run
        self.stats = run.store(batch)  # acted with the exploration policy
        run.update_credit += run.settings.online.utd_ratio * batch.numel()
        self.updates.last = {}

    def sample(self, batch: TensorDictBase) -> TensorDictBase:
        """``process_optim_batch``: a sample per update credit.

        Raises:
            StopIteration: no credit left; the trainer ends this batch's updates.
        """
        run = self.run
        if run.update_credit < 1:
            raise StopIteration
        run.update_credit -= 1
        return online_batch(run.replay, run.learner.online_batches_per_update, self.device)

    def after_updates(self) -> None:
        """``post_steps``: the learner's hook (DUAL: the refit when due), the weights' push."""
        self.run.learner.after_updates()
        self.push(self.cut_points.current, self.run.learner.exploration_policy)

    def log_evaluate_checkpoint(self, batch: TensorDictBase) -> None:
        """``post_steps_log``: log, move the bar; evaluate and checkpoint (a cut point) when due."""
        run, budget = self.run, self.run.settings.budget
        self.bar.update(run.frames - self.bar.n)
        run.log({**self.stats, **self.updates.last}, run.frames, "online/")
        if (signals := online_signals(run.frames, self.stats)) is not None:
            run.online_signals.append(signals)  # the plot's signals, the batch's reward
        if run.frames >= self.next_eval:
            run.evaluate("online")
            self.next_eval += budget.eval_every
        if run.frames >= self.next_save:
            self.clock.tick()
            run.save()
            self.next_save = _next_multiple(run.frames, budget.checkpoint_every)
            self.cut_points.cut = True
        stop_at = run.settings.interrupt_at_frames
        if stop_at is not None and run.frames >= stop_at:
            raise KeyboardInterrupt

    def close_bar(self) -> None:
        """Closes the online frames' bar, before the last lines."""
        if self.bar is not None:
            self.bar.close()

    def finish(self) -> None:
        """``shutdown``: the last evaluation (unless one just ran), the curve and summary."""
        run = self.run
        self.cut_points.shutdown()
        self.close_bar()
        if not run.history or run.history[-1]["frames"] != run.frames:
            run.evaluate("online")
        self.clock.tick()
        run.finish()

    def interrupted(self) -> None:
        """After Ctrl-C or SIGTERM: the checkpoint, the logger closed, one line."""
        run = self.run
        if not self.offline_done:
            run.logger.shutdown()
            run.say(offline_interruption(run))
            return
        self.close_bar()
        self.clock.tick()
        run.save()
        run.logger.shutdown()
        run.say(
            f"interrupted at {run.frames} online frames; checkpoint saved. "
            "Continue with resume=true."
        )


def make_trainer(run: O2ORun) -> tuple[Trainer, OnlinePhase]:
    """TorchRL's ``Trainer`` running ``run``, with the recipe's ops registered as its hooks."""
    cut_points, updates = CutPoints(run), run.update
    trainer = Trainer(
        collector=cut_points,
        total_frames=run.settings.budget.online_frames,
        frame_skip=1,
        optim_steps_per_batch=None,  # as many as the credits allow: sample() stops them
        loss_module=run.learner.update,
        optimization_stepper=updates,
        progress_bar=False,  # OnlinePhase's bar: after the offline phase, from a resume's frames
        auto_log_optim_steps=False,
    )
    trainer.collected_frames = run.frames  # a resumed run's frames count toward the total
    phase = OnlinePhase(run, trainer, cut_points, updates)
    trainer.register_op("setup", phase.offline)
    trainer.register_op("batch_process", phase.store)
    trainer.register_op("process_optim_batch", phase.sample)
    trainer.register_op("post_steps", phase.after_updates)
    trainer.register_op("post_steps_log", phase.log_evaluate_checkpoint)
    trainer.register_op("shutdown", phase.finish)
    return trainer, phase


def run_o2o(cfg: DictConfig, make_learner: Callable[[O2ORun], Learner]) -> O2ORun:
    """Runs (or resumes) one offline-to-online run of ``make_learner``'s algorithm; returns it.

    ``cfg`` must have been validated. The run goes through its offline stages, the
    offline evaluation, then the online phase (collect, store, update, the learner's
    hook, evaluate, checkpoint), on TorchRL's ``Trainer`` (:func:`make_trainer`).

    Ctrl-C or SIGTERM (``interrupt_at_frames``, ``interrupt_at_offline_updates``) ends it
    early with a checkpoint and one line; before the run is built (data, networks), the
    ``KeyboardInterrupt`` propagates: there is nothing of it to save.

    Args:
        cfg (DictConfig): a config that passed :func:`~torchrl_dual.recipe.validate_config`.
        make_learner (callable): ``O2ORun -> Learner``, usually the learner class (e.g.
            ``ALGORITHMS[cfg.algo].learner``).

    Returns:
        O2ORun: the run, finished or interrupted (its ``frames``, ``history`` and
        ``stages_done`` say how far it got).
    """
    # SIGTERM stops a run as Ctrl-C does; the run directory is this run's until it returns
    with signals_as_interrupts(), run_directory_lock(cfg.output_dir):
        run = O2ORun(cfg, make_learner)
        trainer, phase = make_trainer(run)
        try:
            trainer.train()
        except KeyboardInterrupt:
            phase.interrupted()
        finally:  # the workers end with the loop, also on an interrupt or an error
            trainer.collector.shutdown()
        return run
