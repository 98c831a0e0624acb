"""DUAL through TorchRL's ``Trainer``: the recipe's builders, TorchRL's training loop.

``python recipes/torchrl_trainer.py`` composes a run from TorchRL's ConfigStore groups
plus DUAL's (``torchrl_dual.trainers.register_configs``: ``trainer=dual``) and calls
``instantiate(cfg.trainer)(...).train()``. The networks, data and env come from the
recipe's builders (``recipe`` lists recipe overrides, e.g. ``env=pointmaze_umaze``), so
nothing is built twice; the loop, hooks and checkpoint are TorchRL's
(docs/pipeline.md, "With TorchRL's trainers").

    python recipes/torchrl_trainer.py                                  # U-maze, smoke budget
    python recipes/torchrl_trainer.py 'recipe=["budget=smoke","seed=1"]' trainer.save_trainer_file=dual.pt

The budget (frames, updates per batch, refit interval) is the recipe's ``budget``; the
``trainer`` group sets the rest of TorchRL's trainer arguments.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import hydra
from hydra.core.config_store import ConfigStore
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer
from torchrl.trainers import OptimizationStepper

from torchrl_dual.recipe import CONFIG_DIR, DualLearner, O2ORun, compose_checked
from torchrl_dual.trainers import NormalizedScoreLogHook, dual_collector, register_configs


class RunUpdateStepper(OptimizationStepper):
    """The recipe learner's critic-then-actor update (IQL, then Eq. 7) as a TorchRL
    optimization step; its optimizers are the learner's, saved with its modules."""

    def __init__(self, run: O2ORun) -> None:
        self.run = run

    def step(self, trainer: Any, sub_batch):
        from tensordict import TensorDict

        return TensorDict(self.run.update(sub_batch.to(self.run.cfg.device)), batch_size=[])


@dataclass
class TorchRLTrainerConfig:
    """The example's top-level config: TorchRL's ``trainer`` group, and recipe overrides."""

    defaults: list = field(default_factory=lambda: ["_self_", {"trainer": "dual"}])
    recipe: list = field(default_factory=lambda: ["budget=smoke", "progress=false"])
    trainer: Any = None


# TorchRL's groups share names with the recipe's (logger/csv); compose_checked composes the
# recipe's tree apart from them and from this app's running Hydra
register_configs()
ConfigStore.instance().store(name="torchrl_trainer", node=TorchRLTrainerConfig)


def build_trainer(cfg: DictConfig):
    """The recipe's DUAL parts, assembled by the stored ``trainer=dual`` config."""
    recipe_cfg = compose_checked(CONFIG_DIR, list(cfg.recipe))
    run = O2ORun(recipe_cfg, DualLearner)
    learner = run.learner
    budget = recipe_cfg.budget
    # D_offline without the recipe's episode ids, which collected batches do not carry
    offline = ReplayBuffer(storage=LazyTensorStorage(len(run.data)))
    offline.extend(run.data.transitions.exclude("episode"))
    replay = OfflineToOnlineReplayBuffer(
        offline,
        online_capacity=max(int(budget.online_frames), 1),
        offline_fraction=float(recipe_cfg.online.offline_fraction),
        batch_size=int(recipe_cfg.online.batch_size),
    )
    # the budget is the recipe's (recipe=[budget...]), so both paths run the same one
    trainer_cfg = OmegaConf.merge(
        cfg.trainer,
        {
            "total_frames": int(budget.online_frames),
            "refit_interval": int(budget.laplace_refit_every),
            "optim_steps_per_batch": max(
                int(budget.frames_per_batch * recipe_cfg.online.utd_ratio), 1
            ),
        },
    )
    total = int(trainer_cfg.total_frames)
    # the recipe's evaluator (budget.eval_episodes deterministic episodes, its normalized
    # score) every budget.eval_every frames, as the recipe evaluates
    evaluation = NormalizedScoreLogHook(
        lambda: run.evaluate_policy(learner.evaluation_policy),
        interval=max(int(budget.eval_every) // int(budget.frames_per_batch), 1),
    )
    trainer = instantiate(trainer_cfg, _partial_=True)(
        collector=dual_collector(
            run.env,
            learner.policy,
            frames_per_batch=int(budget.frames_per_batch),
            total_frames=total,
        ),
        policy=learner.policy,
        stepper=RunUpdateStepper(run),
        replay_buffer=replay,
        offline_stages=learner.offline_stages(),
        weight_fn=learner.loss.actor_objective.advantage_weights,
        loss_module=learner.loss,
        evaluation=evaluation,
    )
    # the learner's weights and optimizers (teacher, critics, ...) in the trainer checkpoint
    for name, module in learner.modules().items():
        trainer.register_module(f"dual_{name}", module)
    return trainer


@hydra.main(version_base=None, config_name="torchrl_trainer")
def main(cfg: DictConfig) -> None:
    build_trainer(cfg).train()


if __name__ == "__main__":
    main()
