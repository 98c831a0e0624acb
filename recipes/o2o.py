"""DUAL offline-to-online RL, Algorithm 1 of the paper, end to end.

    python recipes/o2o.py                          # PointMaze U-maze, ~15 min on 2 CPU cores
    python recipes/o2o.py env=frozenlake budget=smoke
    python recipes/o2o.py resume=true              # continue an interrupted run

The offline phase pre-trains the diffusion planner, distils it to one step, pre-trains
the weighted MAP actor and the IQL critic and fits the last-layer Laplace posterior;
the online phase acts with the Laplace ensemble plus shift-aware noise through a TorchRL
``Collector`` and fine-tunes on offline and online data. See docs/recipe.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

sys.path.insert(0, str(Path(__file__).resolve().parent))

from o2o_run import DualRun  # noqa: E402


def run(cfg: DictConfig) -> DualRun:
    dual = DualRun(cfg)  # Alg. 1 line 1: data, networks, buffers (or the checkpoint)

    # ---- Offline phase
    dual.stage("planner", dual.pretrain_planner)  # l.3-4: L_VLB (Eq. 3)
    dual.stage("distillation", dual.distill)  # l.5: N=32 -> 1, π_θ and p(s'|s,a)
    dual.stage("actor_critic", dual.pretrain_actor_critic)  # l.6-8: IQL + Eq. 7
    dual.stage("laplace", dual.fit_laplace)  # l.9: Eq. 8
    dual.stage("offline_eval", lambda: dual.evaluate("offline"))

    # ---- Online phase (l.10-18)
    cfg_budget = cfg.budget
    next_eval = (dual.frames // cfg_budget.eval_every + 1) * cfg_budget.eval_every
    next_save = dual.frames + cfg_budget.checkpoint_every
    try:
        for batch in dual.collector():  # l.11-12: a_t ~ Eq. 9 + Eq. 10, env step
            stats = dual.store(batch)  # l.13: D_online ∪= transitions
            losses = dual.train_online(batch.numel())  # l.14-16: critic and actor updates
            if dual.updates_since_refit >= cfg_budget.laplace_refit_every:
                dual.fit_laplace()  # l.17: refit the posterior
            dual.log({**stats, **losses}, dual.frames, "online/")
            if dual.frames >= next_eval:
                dual.evaluate("online")
                next_eval += cfg_budget.eval_every
            if dual.frames >= next_save:
                dual.save()
                next_save += cfg_budget.checkpoint_every
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


@hydra.main(version_base="1.3", config_path="config", config_name="config")
def main(cfg: DictConfig) -> None:
    run(cfg)


if __name__ == "__main__":
    main()
