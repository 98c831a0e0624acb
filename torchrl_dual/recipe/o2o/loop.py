"""One offline-to-online run from start (or checkpoint) to end: :func:`run_o2o`.

The offline stages of the :class:`~torchrl_dual.recipe.Learner` (shared through
``offline_cache`` when set), the offline evaluation, then the online loop of Algorithm 1
(lines 10-18): collect a batch with the exploration policy, store it, run the UTD
updates (each the learner's ``update`` on a sample of the offline and online replay,
counted by :meth:`O2ORun.update`, compiled with ``compile.compile=true``), the learner's
hook (DUAL's Laplace refits), the weight push to the collector's workers, log, evaluate,
checkpoint; the collector is shut down however the loop ends. Every periodic checkpoint
is a cut point: the next batch comes from a new collector, as after a resume
(docs/recipe.md, "Checkpoint and resume").

Ctrl-C and SIGTERM stop a run alike (``interrupts``): in the offline phase at the end of
an update, whose state the stage's loop saves (``stage_checkpoints``; elsewhere the last
checkpoint stays), in the online phase once the batch in hand is processed, or while the
collector collects; the run saves, prints one line and returns.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase

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
from torchrl_dual.recipe.settings.o2o import COLLECTORS


def online_batch(replay: Replay, k: int, device: torch.device) -> TensorDictBase:
    """One update's sample of D_offline ∪ D_online (``replay``) on ``device``.

    A ``[B]`` batch, or ``[k, B]`` (``k`` batches stacked) for a learner with
    :attr:`~torchrl_dual.recipe.Learner.online_batches_per_update` ``k > 1`` (SO2).
    """
    if k == 1:
        return replay.sample().to(device)
    return torch.stack([replay.sample() for _ in range(k)]).to(device)


def run_o2o(cfg: DictConfig, make_learner: Callable[[O2ORun], Learner]) -> O2ORun:
    """Runs (or resumes) one offline-to-online run of ``make_learner``'s algorithm; returns it.

    ``cfg`` must have been validated. The run goes through its offline stages, the
    offline evaluation, then the online phase (collect, store, update, the learner's
    hook, evaluate, checkpoint).

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
        # ---- Offline phase (its shared stages possibly from offline_cache)
        try:
            run_offline_stages(run)
            run.stage("offline_eval", lambda: run.evaluate("offline"))
        except KeyboardInterrupt:
            run.logger.shutdown()
            run.say(offline_interruption(run))
            return run
        return online_phase(run)


def online_phase(run: O2ORun) -> O2ORun:
    """Algorithm 1's online loop (lines 10-18) for ``run``, past its offline phase."""
    cfg = run.cfg
    budget = cfg.budget
    next_eval = (run.frames // budget.eval_every + 1) * budget.eval_every
    next_save = (run.frames // budget.checkpoint_every + 1) * budget.checkpoint_every
    clock = StageClock(run.stage_seconds, run.stage_cpu_seconds, "online")
    push = COLLECTORS[cfg.collector.name].push  # the weights' way to the collector
    device = torch.device(cfg.device)
    collector = None
    try:
        while run.frames < budget.online_frames:
            # A cut point (the start, each checkpoint, a resume): a new collector, its env
            # seeded by seed + 1 + frames, a new episode. An uninterrupted run cuts where a
            # run resumed from its checkpoint does, so the two continue bitwise alike.
            collector = run.collector()
            for batch in collector:
                with held():  # a signal now stops the run after this batch
                    stats = run.store(batch)  # l. 11-13: acted with the exploration policy
                    # l. 14-16: online.utd_ratio gradient updates per collected frame
                    run.update_credit += cfg.online.utd_ratio * batch.numel()
                    losses: dict = {}
                    while run.update_credit >= 1:
                        k = run.learner.online_batches_per_update
                        sample = online_batch(run.replay, k, device)  # D_offline ∪ D_online
                        losses = run.update(sample)  # the learner's (DUAL: IQL critic + Eq. 7)
                        losses.update(run.replay.after_update(sample))  # balanced replay's step
                        run.update_credit -= 1
                    run.learner.after_updates()  # l. 17, DUAL: refit the posterior when due
                    push(collector, run.learner.exploration_policy)  # to the workers
                    run.log({**stats, **losses}, run.frames, "online/")
                    if (signals := online_signals(run.frames, stats)) is not None:
                        run.online_signals.append(signals)  # the plot's signals, the batch's reward
                    if run.frames >= next_eval:
                        run.evaluate("online")
                        next_eval += budget.eval_every
                    checkpoint = run.frames >= next_save
                    if checkpoint:
                        clock.tick()
                        run.save()
                        next_save = (
                            run.frames // budget.checkpoint_every + 1
                        ) * budget.checkpoint_every
                    if (
                        cfg.interrupt_at_frames is not None
                        and run.frames >= cfg.interrupt_at_frames
                    ):
                        raise KeyboardInterrupt
                    if checkpoint:
                        break
            stop_collecting(collector)
            collector = None
    except KeyboardInterrupt:
        clock.tick()
        run.save()
        run.logger.shutdown()
        run.say(
            f"interrupted at {run.frames} online frames; checkpoint saved. "
            "Continue with resume=true."
        )
        return run
    finally:  # the workers end with the loop, also on an interrupt or an error
        if collector is not None:
            collector.shutdown()
    if not run.history or run.history[-1]["frames"] != run.frames:
        run.evaluate("online")
    clock.tick()
    run.finish()
    return run
