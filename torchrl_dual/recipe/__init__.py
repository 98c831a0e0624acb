"""The offline-to-online recipe as a library: tables, a validated config, Algorithm 1.

:func:`main` is the program (the ``torchrl-dual`` console script, ``python -m
torchrl_dual.recipe`` and ``recipes/o2o.py``) and :data:`CONFIG_DIR` its Hydra config
tree, shipped in the package; everything it runs lives here, so that a ``pip install``
gets it too:

* :data:`ENV_KITS` (``env_kits``) — one entry per ``env.kind``: offline data, train env,
  evaluator, action projection;
* :data:`ALGORITHMS` (``algorithms``) — one entry per ``algo``: an :class:`Algorithm`
  (``algorithm``: config sections, critics, cross-key checks, :class:`Learner`) defined
  next to its learner: ``dual`` (``dual_settings``), ``iql``, ``iql_la``, ``diffql``,
  ``diffql_la`` (``diffql``), ``diffuser``, ``dacer``, ``edis``;
* :data:`CRITICS` (``critics``) — one entry per ``critic.name``;
* :data:`~torchrl_dual.recipe.o2o.loggers.LOGGERS` (``loggers``) — one entry per
  ``logger.backend`` (CSV, TensorBoard, W&B, ...); ``plots`` draws the end-of-run plot;
* :func:`validate_config` (``schema``) — the schema of every config group, checked
  before any data or network; errors are :class:`UserError` (``errors``), reported as
  one ``error:`` line and exit code 2;
* :class:`O2ORun` / :func:`run_o2o` / :class:`Learner` (``o2o_run``) — the
  algorithm-independent offline-to-online run (data, env, evaluator, replay, collector,
  UTD updates, evaluation, checkpoint and resume) and the protocol of an algorithm;
  ``offline_cache`` shares an offline phase between runs that differ only in online
  keys; ``run_summary`` writes each finished run's ``summary.json``;
* :class:`DualLearner` / :func:`run_dual` (``dual``) — Algorithm 1;
  :class:`IQLLearner` / :func:`run_iql` (``iql``) — the IQL baseline; the other
  baselines in ``iql_la``, ``diffql``, ``diffuser``, ``dacer``, ``edis`` (``laplace_refits``: their
  shared Laplace refit schedule; ``planner_stage``: the planner's offline stage;
  ``planner_augment``: Algorithm 1 line 14's planner augmentation, also DUAL's
  ``augment.kind=planner``).
"""

from torchrl_dual.recipe.algos.dual import DualLearner, run_dual
from torchrl_dual.recipe.algos.iql import IQLLearner, run_iql
from torchrl_dual.recipe.algos.table import ALGORITHMS
from torchrl_dual.recipe.cli import (
    CONFIG_DIR,
    check_command_line,
    compose_checked,
    hydra_task,
    main,
    run,
)
from torchrl_dual.recipe.kits.build import ENV_KITS, EnvKit
from torchrl_dual.recipe.o2o.learner import Learner
from torchrl_dual.recipe.o2o.loop import run_o2o
from torchrl_dual.recipe.o2o.plots import plot_learning_curve
from torchrl_dual.recipe.o2o.run import O2ORun
from torchrl_dual.recipe.parts.critics import CRITICS
from torchrl_dual.recipe.settings.algos import Algorithm
from torchrl_dual.recipe.settings.errors import ConfigError, UserError, user_errors
from torchrl_dual.recipe.settings.schema import validate_config

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
    "UserError",
    "check_command_line",
    "compose_checked",
    "hydra_task",
    "main",
    "plot_learning_curve",
    "run",
    "run_dual",
    "run_iql",
    "run_o2o",
    "user_errors",
    "validate_config",
]
