"""One offline-to-online run from start (or checkpoint) to end: :func:`run_o2o`.

The offline stages of the :class:`~torchrl_dual.recipe.Learner` (shared through
``offline_cache`` when set), the offline evaluation, then the online loop of Algorithm 1
(lines 10-18): collect a batch with the exploration policy, store it, run the UTD
updates, the learner's hook (DUAL's Laplace refits), the weight push to the collector's
workers, log, evaluate, checkpoint; the collector is shut down however the loop ends.
"""

from __future__ import annotations

from collections.abc import Callable

from omegaconf import DictConfig

from torchrl_dual.recipe.o2o.learner import Learner
from torchrl_dual.recipe.o2o.offline_cache import run_offline_stages
from torchrl_dual.recipe.o2o.plots import online_signals
from torchrl_dual.recipe.o2o.run import O2ORun
from torchrl_dual.recipe.o2o.stage_clock import StageClock
from torchrl_dual.recipe.settings.o2o import COLLECTORS


def run_o2o(cfg: DictConfig, make_learner: Callable[[O2ORun], Learner]) -> O2ORun:
    """Runs (or resumes) one offline-to-online run of ``make_learner``'s algorithm for a
    validated ``cfg``: its offline stages, the offline evaluation, then the online phase
    (collect, store, update, the learner's hook, evaluate, checkpoint); returns the run."""
    run = O2ORun(cfg, make_learner)

    # ---- Offline phase (its shared stages possibly from offline_cache)
    run_offline_stages(run)
    run.stage("offline_eval", lambda: run.evaluate("offline"))

    # ---- Online phase
    budget = cfg.budget
    next_eval = (run.frames // budget.eval_every + 1) * budget.eval_every
    next_save = run.frames + budget.checkpoint_every
    clock = StageClock(run.stage_seconds, run.stage_cpu_seconds, "online")
    collector = run.collector() if run.frames < budget.online_frames else None
    push = COLLECTORS[cfg.collector.name].push  # the weights' way to the collector
    try:
        for batch in collector if collector is not None else ():
            stats = run.store(batch)  # act with the exploration policy, store in D_online
            losses = run.train_online(batch.numel())  # UTD-ratio updates
            run.learner.after_updates()  # DUAL: refit the Laplace posterior when due
            push(collector, run.learner.exploration_policy)  # to the workers
            run.log({**stats, **losses}, run.frames, "online/")
            if (signals := online_signals(run.frames, stats)) is not None:
                run.online_signals.append(signals)  # the plot's epistemic std and d_t
            if run.frames >= next_eval:
                run.evaluate("online")
                next_eval += budget.eval_every
            if run.frames >= next_save:
                clock.tick()
                run.save()
                next_save += budget.checkpoint_every
            if cfg.interrupt_at_frames is not None and run.frames >= cfg.interrupt_at_frames:
                raise KeyboardInterrupt
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
