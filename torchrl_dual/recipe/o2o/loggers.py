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

from omegaconf import DictConfig, OmegaConf
from torchrl.record.loggers import Logger, get_logger


def make_logger(
    cfg: DictConfig,
    log_dir: Path,
    exp_name: str,
    state: dict | None = None,
    previous: Logger | None = None,
) -> Logger:
    """The TorchRL logger of ``cfg.logger`` writing under ``log_dir``.

    It continues ``state`` (a ``Logger.state_dict()`` of a checkpoint) if given.

    The run writes where it is now, whatever directory ``state`` was saved from (a moved
    ``output_dir``; a shared offline phase's snapshot); this also avoids TorchRL 0.14.1's
    ``TensorboardLogger`` nesting ``exp_name`` once more on every resume. ``previous``
    (the run's current logger, replaced by a snapshot's state) is closed, and a W&B run
    keeps its own run id.

    Examples:
        >>> import tempfile
        >>> from omegaconf import OmegaConf
        >>> cfg = OmegaConf.create({"logger": {"backend": "csv"}})
        >>> logs = Path(tempfile.mkdtemp())
        >>> logger = make_logger(cfg, logs, "dual")
        >>> logger.log_scalar("online/reward_per_step", 0.5, step=100)
        >>> resumed = make_logger(cfg, logs, "dual", state=logger.state_dict())
        >>> resumed.log_scalar("online/reward_per_step", 0.25, step=200)
        >>> (logs / "dual" / "scalars" / "online" / "reward_per_step.csv").read_text().split()
        ['100,0.5', '200,0.25']
    """
    kwargs: dict[str, Any] = {}
    if cfg.logger.backend == "wandb":
        kwargs["wandb_kwargs"] = {
            "project": cfg.logger.project,
            "entity": cfg.logger.entity,
            "mode": cfg.logger.mode,
            # several runs in one process (tests, notebooks): each its own W&B run
            "reinit": "create_new",
            "config": OmegaConf.to_container(cfg, resolve=True),
        }
    if state is not None:
        state = {**state, "log_dir": str(log_dir), "exp_name": exp_name}
        if previous is not None and cfg.logger.backend == "wandb":
            state["local"] = {**state.get("local", {}), "id": previous.experiment.id}
    if previous is not None:
        previous.shutdown()
    return get_logger(cfg.logger.backend, str(log_dir), exp_name, state_dict=state, **kwargs)


def logs_text(cfg: DictConfig, log_dir: Path, exp_name: str) -> str:
    """Where a finished run's metrics are and how to look at them, for the console.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> logs_text(OmegaConf.create({"logger": {"backend": "tensorboard"}}), Path("logs"), "dual")
        'TensorBoard logs: logs/dual (tensorboard --logdir logs)'
    """
    backend = cfg.logger.backend
    if backend == "csv":
        return f"metrics CSV: {log_dir / exp_name / 'scalars'}"
    if backend == "tensorboard":
        return f"TensorBoard logs: {log_dir / exp_name} (tensorboard --logdir {log_dir})"
    if backend == "wandb" and cfg.logger.mode == "offline":
        return f"W&B offline run: {log_dir / 'wandb'} (upload: wandb sync {log_dir}/wandb/offline-run-*)"
    return f"metrics: logger.backend={backend}"
