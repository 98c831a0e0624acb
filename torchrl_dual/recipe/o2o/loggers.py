"""The recipe's metrics loggers: a table by ``logger.backend`` over TorchRL's ``get_logger``.

Every backend receives the same scalars (``O2ORun.log`` and the offline stages call
``log_scalar`` only): ``csv`` (the default, one CSV file per scalar), ``tensorboard``
(event files for ``tensorboard --logdir``) and ``wandb`` (Weights & Biases; ``mode:
offline`` by default, so it needs no account, and ``wandb sync`` uploads the run later)
all under ``<output_dir>/logs``; ``mlflow`` and ``trackio`` as TorchRL builds them.
The logger's state is part of the run's checkpoint (TorchRL's
``Logger.state_dict``): a resumed run continues the CSV files, the TensorBoard directory
and the same W&B run (its run id).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from torchrl.record.loggers import Logger, get_logger

from torchrl_dual.recipe.settings.loggers import LoggerSettings


def make_logger(
    logger: LoggerSettings,
    log_dir: Path,
    exp_name: str,
    state: dict | None = None,
    previous: Logger | None = None,
    run_config: dict | None = None,
) -> Logger:
    """The TorchRL logger of the ``logger`` section writing under ``log_dir``.

    It continues ``state`` (a ``Logger.state_dict()`` of a checkpoint) if given. A W&B
    run records ``run_config`` (the run's resolved config) as its config.

    The run writes where it is now, whatever directory ``state`` was saved from (a moved
    ``output_dir``; a shared offline phase's snapshot); this also avoids TorchRL 0.14.1's
    ``TensorboardLogger`` nesting ``exp_name`` once more on every resume. ``previous``
    (the run's current logger, replaced by a snapshot's state) is closed, and a W&B run
    keeps its own run id.

    Examples:
        >>> import tempfile
        >>> logs = Path(tempfile.mkdtemp())
        >>> logger = make_logger(LoggerSettings(backend="csv"), logs, "dual")
        >>> logger.log_scalar("online/reward_per_step", 0.5, step=100)
        >>> resumed = make_logger(LoggerSettings(backend="csv"), logs, "dual",
        ...                       state=logger.state_dict())
        >>> resumed.log_scalar("online/reward_per_step", 0.25, step=200)
        >>> (logs / "dual" / "scalars" / "online" / "reward_per_step.csv").read_text().split()
        ['100,0.5', '200,0.25']
    """
    kwargs: dict[str, Any] = {}
    if logger.backend == "wandb":
        kwargs["wandb_kwargs"] = {
            "project": logger.project,
            "entity": logger.entity,
            "mode": logger.mode,
            # several runs in one process (tests, notebooks): each its own W&B run
            "reinit": "create_new",
            "config": run_config,
        }
    if state is not None:
        state = {**state, "log_dir": str(log_dir), "exp_name": exp_name}
        if previous is not None and logger.backend == "wandb":
            state["local"] = {**state.get("local", {}), "id": previous.experiment.id}
    if previous is not None:
        previous.shutdown()
    return get_logger(logger.backend, str(log_dir), exp_name, state_dict=state, **kwargs)


def logs_text(logger: LoggerSettings, log_dir: Path, exp_name: str) -> str:
    """Where a finished run's metrics are and how to look at them, for the console.

    Examples:
        >>> logs_text(LoggerSettings(backend="tensorboard"), Path("logs"), "dual")
        'TensorBoard logs: logs/dual (tensorboard --logdir logs)'
    """
    backend = logger.backend
    if backend == "csv":
        return f"metrics CSV: {log_dir / exp_name / 'scalars'}"
    if backend == "tensorboard":
        return f"TensorBoard logs: {log_dir / exp_name} (tensorboard --logdir {log_dir})"
    if backend == "wandb" and logger.mode == "offline":
        return f"W&B offline run: {log_dir / 'wandb'} (upload: wandb sync {log_dir}/wandb/offline-run-*)"
    return f"metrics: logger.backend={backend}"
