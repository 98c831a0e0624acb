"""DUAL through TorchRL's ``Trainer``: the recipe's builders, TorchRL's training loop.

    python recipes/torchrl_trainer.py                              # U-maze, smoke budget
    python recipes/torchrl_trainer.py seed=1 env=frozenlake trainer.save_trainer_file=dual.pt

The command line is the recipe's (``torchrl-dual``'s overrides; ``budget`` defaults to
``smoke`` here) plus ``trainer.*`` keys, which set TorchRL's trainer config ``trainer=dual``
(``torchrl_dual.trainers.register_configs``). The data, env, networks and offline stages
come from the recipe's builders, so nothing is built twice; the budget (frames, updates
per batch, refit interval) is the recipe's ``budget``; the loop, hooks and checkpoint are
TorchRL's (docs/pipeline.md, "With TorchRL's trainers"). A bad override, like any of the
recipe's user errors, ends in one ``error:`` line and exit code 2; a finished run prints
its final normalized score.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from typing import Any

from hydra import compose, initialize
from hydra.core.config_store import ConfigStore
from hydra.errors import HydraException
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked, user_errors

DEFAULTS = {"budget": "budget=smoke", "progress": "progress=false"}
"""Recipe overrides the script adds unless the command line sets the key."""


def split_overrides(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """``(recipe overrides, trainer overrides)``: ``trainer.*`` keys are TorchRL's."""
    trainer = [o for o in argv if o.lstrip("+~").startswith("trainer.")]
    recipe = [o for o in argv if o not in trainer]
    given = {o.lstrip("+~").split("=", 1)[0] for o in recipe}
    return [*(o for key, o in DEFAULTS.items() if key not in given), *recipe], trainer


def compose_configs(argv: Sequence[str]) -> tuple[DictConfig, DictConfig]:
    """The recipe's validated config and TorchRL's ``trainer=dual`` config for the command
    line ``argv``.

    Raises:
        ConfigError: anything the recipe's command line refuses, another ``algo`` than
            ``dual``, or a ``trainer.*`` override Hydra cannot apply.
    """
    from torchrl_dual.trainers import register_configs

    recipe, overrides = split_overrides(argv)
    recipe_cfg = compose_checked(CONFIG_DIR, recipe)  # the recipe's tree, apart from TorchRL's
    if recipe_cfg.algo != "dual":
        raise ConfigError(
            "algo", recipe_cfg.algo, "this script trains DUAL; run the recipe for the others"
        )
    register_configs()
    ConfigStore.instance().store(
        name="torchrl_trainer", node={"defaults": ["_self_", {"trainer": "dual"}]}
    )
    try:
        with initialize(version_base=None):
            return recipe_cfg, compose("torchrl_trainer", overrides=overrides).trainer
    except (HydraException, OmegaConfBaseException) as err:
        message = str(err).splitlines()[0].rstrip(".")  # Hydra's hint to append is not ours
        cause = "" if err.__cause__ is None else f": {str(err.__cause__).splitlines()[0]}"
        raise ConfigError(None, None, message + cause) from err


def build_trainer(recipe_cfg: DictConfig, trainer_cfg: DictConfig) -> Any:
    """The recipe's DUAL parts, assembled by the stored ``trainer=dual`` config."""
    from torchrl.data import LazyTensorStorage, OfflineToOnlineReplayBuffer, ReplayBuffer
    from torchrl.trainers import OptimizationStepper

    from torchrl_dual.recipe import DualLearner, O2ORun
    from torchrl_dual.trainers import NormalizedScoreLogHook, dual_collector

    class RunUpdateStepper(OptimizationStepper):
        """The recipe learner's critic-then-actor update (IQL, then Eq. 7) as a TorchRL
        optimization step; its optimizers are the learner's, saved with its modules."""

        def step(self, trainer: Any, sub_batch):
            from tensordict import TensorDict

            return TensorDict(run.update(sub_batch.to(recipe_cfg.device)), batch_size=[])

    run = O2ORun(recipe_cfg, DualLearner)
    learner, budget = run.learner, recipe_cfg.budget
    # D_offline without the recipe's episode ids, which collected batches do not carry
    offline = ReplayBuffer(storage=LazyTensorStorage(len(run.data)))
    offline.extend(run.data.transitions.exclude("episode"))
    replay = OfflineToOnlineReplayBuffer(
        offline,
        online_capacity=max(int(budget.online_frames), 1),
        offline_fraction=float(recipe_cfg.online.offline_fraction),
        batch_size=int(recipe_cfg.online.batch_size),
    )
    # the budget is the recipe's, so both paths run the same one
    trainer_cfg = OmegaConf.merge(
        trainer_cfg,
        {
            "total_frames": int(budget.online_frames),
            "refit_interval": int(budget.laplace_refit_every),
            "optim_steps_per_batch": max(
                int(budget.frames_per_batch * recipe_cfg.online.utd_ratio), 1
            ),
        },
    )
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
            total_frames=int(trainer_cfg.total_frames),
        ),
        policy=learner.policy,
        stepper=RunUpdateStepper(),
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


def main(argv: Sequence[str] | None = None) -> Any:
    """Trains DUAL for the command line's overrides, prints its final score and returns
    the trainer."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if {"-h", "--help"} & set(argv):
        print(__doc__)
        return None
    with user_errors(debug="debug=true" in argv):
        trainer = build_trainer(*compose_configs(argv))
    trainer.train()
    score = trainer._modules["normalized_score"].evaluate()["normalized_score"]
    print(
        f"[dual] TorchRL Trainer: {trainer.collected_frames} online frames, final "
        f"normalized score {float(score):.1f}",
        flush=True,
    )
    return trainer


if __name__ == "__main__":
    main()
