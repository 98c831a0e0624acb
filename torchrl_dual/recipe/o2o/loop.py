"""One offline-to-online run from start (or checkpoint) to end: :func:`run_o2o`.

The offline stages of the :class:`~torchrl_dual.recipe.Learner` (shared through
``offline_cache`` when set), the offline evaluation, then the online loop of Algorithm 1
(lines 10-18): collect a batch with the exploration policy, store it, run the UTD
updates (each the learner's ``update`` on a sample of the offline and online replay,
counted by :meth:`O2ORun.update`, compiled with ``compile.compile=true``), the learner's
hook (DUAL's Laplace refits), the weight push to the collector's workers, log, evaluate,
checkpoint; the collector is shut down however the loop ends.
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from omegaconf import DictConfig
from tensordict import TensorDictBase

from torchrl_dual.recipe.o2o.learner import Learner
from torchrl_dual.recipe.o2o.offline_cache import run_offline_stages
from torchrl_dual.recipe.o2o.plots import online_signals
from torchrl_dual.recipe.o2o.replays import Replay
from torchrl_dual.recipe.o2o.run import O2ORun
from torchrl_dual.recipe.o2o.stage_clock import StageClock
from torchrl_dual.recipe.settings.o2o import COLLECTORS


def online_batch(replay: Replay, k: int, device: torch.device) -> TensorDictBase:
    """One update's sample of D_offline ∪ D_online (``replay``) on ``device``: a ``[B]``
    batch, or ``[k, B]`` (``k`` batches stacked) for a learner with
    :attr:`~torchrl_dual.recipe.Learner.online_batches_per_update` ``k > 1`` (SO2)."""
    if k == 1:
        return replay.sample().to(device)
    return torch.stack([replay.sample() for _ in range(k)]).to(device)


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
    device = torch.device(cfg.device)
    try:
        for batch in collector if collector is not None else ():
            stats = run.store(batch)  # l. 11-13: acted with the exploration policy -> D_online
            # l. 14-16: online.utd_ratio gradient updates per collected frame
            run.update_credit += cfg.online.utd_ratio * batch.numel()
            losses: dict = {}
            while run.update_credit >= 1:
                sample = online_batch(run.replay, run.learner.online_batches_per_update, device)
                losses = run.update(sample)  # the learner's update (DUAL: IQL critic + Eq. 7)
                losses.update(run.replay.after_update(sample))  # balanced replay's own step
                run.update_credit -= 1
            run.learner.after_updates()  # l. 17, DUAL: refit the Laplace posterior when due
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
