"""Algorithm 1 of the paper (DUAL, offline then online), one call per step.

The offline phase pre-trains the diffusion planner, distils it to one step, pre-trains
the weighted MAP actor and the critic and fits the last-layer Laplace posterior; the
online phase acts with the Laplace ensemble plus shift-aware noise through a TorchRL
``Collector`` and fine-tunes on offline and online data. See docs/recipe.md.
"""

from __future__ import annotations

from omegaconf import DictConfig

from torchrl_dual.recipe.dual_run import DualRun


def run_dual(cfg: DictConfig) -> DualRun:
    """Runs (or resumes) Algorithm 1 for a validated ``cfg``; returns the run's state."""
    dual = DualRun(cfg)  # Alg. 1 line 1: data, networks, buffers (or the checkpoint)

    # ---- Offline phase
    dual.stage("planner", dual.pretrain_planner)  # l.3-4: L_VLB (Eq. 3)
    dual.stage("distillation", dual.distill)  # l.5: N=32 -> 1, π_θ and p(s'|s,a)
    dual.stage("actor_critic", dual.pretrain_actor_critic)  # l.6-8: IQL + Eq. 7
    dual.stage("laplace", dual.fit_laplace)  # l.9: Eq. 8
    dual.stage("offline_eval", lambda: dual.evaluate("offline"))

    # ---- Online phase (l.10-18)
    budget = cfg.budget
    next_eval = (dual.frames // budget.eval_every + 1) * budget.eval_every
    next_save = dual.frames + budget.checkpoint_every
    try:
        for batch in dual.collector() if dual.frames < budget.online_frames else ():
            stats = dual.store(batch)  # l.11-13: a_t ~ Eq. 9 + Eq. 10, env step, D_online
            losses = dual.train_online(batch.numel())  # l.14-16: critic and actor updates
            if dual.updates_since_refit >= budget.laplace_refit_every:
                dual.fit_laplace()  # l.17: refit the posterior
            dual.log({**stats, **losses}, dual.frames, "online/")
            if dual.frames >= next_eval:
                dual.evaluate("online")
                next_eval += budget.eval_every
            if dual.frames >= next_save:
                dual.save()
                next_save += budget.checkpoint_every
            if cfg.interrupt_at_frames is not None and dual.frames >= cfg.interrupt_at_frames:
                raise KeyboardInterrupt
    except KeyboardInterrupt:
        dual.save()
        print(
            f"[dual] interrupted at {dual.frames} online frames; checkpoint saved. "
            "Continue with resume=true."
        )
        return dual
    if not dual.history or dual.history[-1]["frames"] != dual.frames:
        dual.evaluate("online")
    dual.finish()
    return dual
