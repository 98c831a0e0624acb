"""The offline-to-online recipe as a library: tables, a validated config, Algorithm 1.

:func:`main` is the program (the ``torchrl-dual`` console script, ``python -m
torchrl_dual.recipe`` and ``recipes/o2o.py``) and :data:`CONFIG_DIR` its Hydra config
tree, shipped in the package. Five subpackages, each importing only the ones after it:

* ``algos`` — one learner per algorithm: :class:`DualLearner` (``algos/dual.py``,
  Algorithm 1), :class:`IQLLearner` and the other baselines;
* ``parts`` — what several algorithms share: the critics, DUAL's network builders, the
  Laplace fits, the planner's offline stage and augmentation, Cal-QL's labels;
* ``o2o`` — the algorithm-independent run: :class:`O2ORun`, :func:`run_o2o` (TorchRL's ``Trainer``),
  :class:`Learner`, replays, collectors, loggers, checkpoint and resume;
* ``kits`` — the env kits' data, envs and evaluators;
* ``settings`` — the config schema and the tables :data:`ALGORITHMS`,
  :data:`ENV_KITS`, :data:`CRITICS` (and the replays, collectors and loggers), each
  entry a schema plus a reference to its builder; :func:`validate_config` and the
  :class:`UserError` path (one ``error:`` line, exit code 2). It imports neither torch
  nor TorchRL, so a bad config value is reported at once.

The names below are imported on first use (``docs/architecture.md``, "The recipe's
modules", lists every module).
"""

from typing import TYPE_CHECKING

from torchrl_dual._lazy import lazy_exports

if TYPE_CHECKING:  # the eager imports, for type checkers and IDEs
    from torchrl_dual.recipe.algos.dual import DualLearner
    from torchrl_dual.recipe.algos.iql import IQLLearner
    from torchrl_dual.recipe.cli import (
        CONFIG_DIR,
        check_command_line,
        compose_checked,
        hydra_task,
        main,
        run,
    )
    from torchrl_dual.recipe.o2o.learner import Learner
    from torchrl_dual.recipe.o2o.loop import run_o2o
    from torchrl_dual.recipe.o2o.plots import plot_learning_curve
    from torchrl_dual.recipe.o2o.run import O2ORun
    from torchrl_dual.recipe.settings.algo_common import Algorithm
    from torchrl_dual.recipe.settings.algos import ALGORITHMS
    from torchrl_dual.recipe.settings.envs import ENV_KITS, EnvKit
    from torchrl_dual.recipe.settings.errors import ConfigError, UserError, user_errors
    from torchrl_dual.recipe.settings.parts import CRITICS
    from torchrl_dual.recipe.settings.schema import validate_config
    from torchrl_dual.recipe.settings.structured import RecipeSettings, store_schemas, typed_config

__all__ = [
    "ALGORITHMS",
    "CONFIG_DIR",
    "CRITICS",
    "ENV_KITS",
    "Algorithm",
    "ConfigError",
    "DualLearner",
    "EnvKit",
    "IQLLearner",
    "Learner",
    "O2ORun",
    "RecipeSettings",
    "UserError",
    "check_command_line",
    "compose_checked",
    "hydra_task",
    "main",
    "plot_learning_curve",
    "run",
    "run_o2o",
    "store_schemas",
    "typed_config",
    "user_errors",
    "validate_config",
]

__getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "DualLearner": "torchrl_dual.recipe.algos.dual",
        "IQLLearner": "torchrl_dual.recipe.algos.iql",
        "CONFIG_DIR": "torchrl_dual.recipe.cli",
        "check_command_line": "torchrl_dual.recipe.cli",
        "compose_checked": "torchrl_dual.recipe.cli",
        "hydra_task": "torchrl_dual.recipe.cli",
        "main": "torchrl_dual.recipe.cli",
        "run": "torchrl_dual.recipe.cli",
        "ENV_KITS": "torchrl_dual.recipe.settings.envs",
        "EnvKit": "torchrl_dual.recipe.settings.envs",
        "Learner": "torchrl_dual.recipe.o2o.learner",
        "run_o2o": "torchrl_dual.recipe.o2o.loop",
        "plot_learning_curve": "torchrl_dual.recipe.o2o.plots",
        "O2ORun": "torchrl_dual.recipe.o2o.run",
        "ALGORITHMS": "torchrl_dual.recipe.settings.algos",
        "Algorithm": "torchrl_dual.recipe.settings.algo_common",
        "ConfigError": "torchrl_dual.recipe.settings.errors",
        "UserError": "torchrl_dual.recipe.settings.errors",
        "user_errors": "torchrl_dual.recipe.settings.errors",
        "CRITICS": "torchrl_dual.recipe.settings.parts",
        "validate_config": "torchrl_dual.recipe.settings.schema",
        "RecipeSettings": "torchrl_dual.recipe.settings.structured",
        "store_schemas": "torchrl_dual.recipe.settings.structured",
        "typed_config": "torchrl_dual.recipe.settings.structured",
    },
)
