"""The gradient-update loop shared by the training drivers, and a parameter EMA.

:func:`run_updates` can be checkpointed within the loop and resumed from there
(:class:`UpdateCheckpoints`): what it saves is everything the loop itself holds (the
loss module's weights, the optimizer, the learning-rate schedule, the EMA and the
running log window), so a loop resumed from its state ends exactly as an uninterrupted
one, given the same random state (the caller's to keep).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase
from torchrl.objectives.common import LossModule
from tqdm.auto import tqdm


class ExponentialMovingAverage:
    """An exponential moving average of a module's floating-point parameters.

    Examples:
        >>> import torch
        >>> net = torch.nn.Linear(2, 1)
        >>> ema = ExponentialMovingAverage(net, decay=0.9)
        >>> with torch.no_grad():
        ...     _ = net.weight.add_(1.0)
        >>> ema.update(); ema.copy_to(net)
    """

    def __init__(self, module: torch.nn.Module, decay: float = 0.999) -> None:
        if not 0.0 <= decay < 1.0:
            raise ValueError(f"EMA decay must lie in [0, 1), got {decay}.")
        self.decay = decay
        self.params = [p for p in module.parameters() if p.is_floating_point()]
        self.shadow = [p.detach().clone() for p in self.params]

    @torch.no_grad()
    def update(self) -> None:
        """Moves each average toward its parameter: ``θ̄ ← decay·θ̄ + (1 − decay)·θ``."""
        torch._foreach_lerp_(self.shadow, [p.detach() for p in self.params], 1.0 - self.decay)

    def state_dict(self) -> dict[str, list[torch.Tensor]]:
        """The averages (copies), for a checkpoint."""
        return {"shadow": [average.clone() for average in self.shadow]}

    @torch.no_grad()
    def load_state_dict(self, state: dict[str, list[torch.Tensor]]) -> None:
        """Restores what :meth:`state_dict` returned."""
        for average, saved in zip(self.shadow, state["shadow"], strict=True):
            average.copy_(saved)

    @torch.no_grad()
    def copy_to(self, module: torch.nn.Module) -> None:
        """Writes the averages into ``module`` (the module the EMA was built on)."""
        for param, average in zip(module.parameters(), self.shadow, strict=True):
            param.copy_(average)


class UpdateCheckpoints(Protocol):
    """Where a resumable update loop (:func:`run_updates`) finds and leaves its progress.

    The recipe's offline stages pass one (``O2ORun.stage_checkpoints``): it saves the run
    with the loop's state every so many updates and when the run is interrupted.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> from torchrl_dual.objectives import DiffusionPlannerLoss
        >>> class InMemory:  # keeps the last state; interrupts the loop once, at update 2
        ...     saved, stop_at = None, 2
        ...     def resume(self):
        ...         return self.saved
        ...     def after_update(self, done, total, state):
        ...         self.saved = state()
        ...         if done == self.stop_at:
        ...             self.stop_at = None
        ...             raise KeyboardInterrupt
        >>> model = TrajectoryDiffusion(TrajectoryLayout(2, 1, 3), hidden=16, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 2), torch.randn(64, 1))
        >>> loss = DiffusionPlannerLoss(model)
        >>> optimizer = torch.optim.Adam(loss.parameters())
        >>> windows = lambda: TensorDict(observation=torch.randn(4, 4, 2),
        ...                              action=torch.randn(4, 4, 1), batch_size=[4, 4])
        >>> checkpoints = InMemory()
        >>> run = lambda: run_updates(loss, windows, 5, optimizer, progress=False,
        ...                           checkpoints=checkpoints)
        >>> try:
        ...     _ = run()
        ... except KeyboardInterrupt:
        ...     print("interrupted after update", checkpoints.saved["done"])
        interrupted after update 2
        >>> _ = run()
        >>> checkpoints.saved["done"]  # resumed at update 2, finished at 5
        5
    """

    def resume(self) -> dict[str, Any] | None:
        """The loop state to continue from, or ``None`` to start at update 0.

        What an ``after_update`` call's ``state()`` returned; called right before
        the loop runs.
        """

    def after_update(self, done: int, total: int, state: Callable[[], dict[str, Any]]) -> None:
        """Called after each update with the progress and a builder of the loop's state.

        ``done`` of ``total`` updates are done and ``state()`` is the loop's state
        now (built only when called). May raise ``KeyboardInterrupt`` to stop the
        loop there.
        """


def run_updates(
    loss_module: LossModule,
    sample: Callable[[], TensorDictBase],
    num_updates: int,
    optimizer: torch.optim.Optimizer,
    *,
    grad_clip: float | None = 1.0,
    desc: str = "updates",
    logger=None,
    log_prefix: str = "",
    log_every: int = 100,
    step_offset: int = 0,
    progress: bool = True,
    cosine_lr: bool = False,
    ema: ExponentialMovingAverage | None = None,
    checkpoints: UpdateCheckpoints | None = None,
) -> dict[str, float]:
    """Runs ``num_updates`` gradient steps on the sum of the ``loss_*`` entries.

    Scalar entries of the loss output are averaged over each ``log_every`` window
    and sent to ``logger`` (a :class:`torchrl.record.loggers.Logger`) as
    ``{log_prefix}{name}``; the last window's averages are returned. With
    ``checkpoints``, the loop continues from the state its ``resume()`` returns and hands
    its state to ``after_update`` after each step (:class:`UpdateCheckpoints`).

    Args:
        loss_module (LossModule): its output's ``loss_*`` entries are summed and
            minimised; every scalar entry is averaged for the log.
        sample (callable): ``() -> TensorDictBase``, the batch of one update.
        num_updates (int): gradient steps (in all, counting those before a resume).
        optimizer (torch.optim.Optimizer): steps the loss module's parameters.

    Keyword Args:
        grad_clip (float, optional): gradient-norm clip over the parameters that require
            a gradient. Defaults to ``1.0``; ``None`` turns it off.
        desc (str): the progress bar's label. Defaults to ``"updates"``.
        logger (Logger, optional): a TorchRL logger, see above.
        log_prefix (str): put before each logged name. Defaults to ``""``.
        log_every (int): updates per averaged window. Defaults to ``100``.
        step_offset (int): added to the logged step (the update count). Defaults to ``0``.
        progress (bool): show a tqdm progress bar. Defaults to ``True``.
        cosine_lr (bool): decay the learning rate along a cosine over ``num_updates``.
            Defaults to ``False``.
        ema (ExponentialMovingAverage, optional): updated after each step.
        checkpoints (UpdateCheckpoints, optional): where the loop resumes from and
            leaves its state.

    Returns:
        dict[str, float]: the last window's average of each scalar entry.

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> from torchrl_dual.objectives import DiffusionPlannerLoss
        >>> from tensordict import TensorDict
        >>> model = TrajectoryDiffusion(TrajectoryLayout(2, 1, 3), hidden=16, depth=1)
        >>> _ = model.normalizer.fit(torch.randn(64, 2), torch.randn(64, 1))
        >>> loss = DiffusionPlannerLoss(model)
        >>> batch = lambda: TensorDict({"observation": torch.randn(4, 4, 2),
        ...     "action": torch.randn(4, 4, 1)}, batch_size=[4, 4])
        >>> stats = run_updates(loss, batch, 3, torch.optim.Adam(loss.parameters()), progress=False)
        >>> sorted(stats)
        ['loss_diffusion', 'x0_error']
    """
    params = [p for p in loss_module.parameters() if p.requires_grad]
    scheduler = (
        torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, max(num_updates, 1))
        if cosine_lr
        else None
    )
    sums: dict[str, torch.Tensor] = {}  # on the device: read back once per window
    count = start = 0
    averages: dict[str, float] = {}

    def loop_state() -> dict[str, Any]:
        return {
            "done": update + 1,
            "loss": loss_module.state_dict(),
            "optimizer": optimizer.state_dict(),
            "scheduler": None if scheduler is None else scheduler.state_dict(),
            "ema": None if ema is None else ema.state_dict(),
            "sums": dict(sums),
            "count": count,
            "averages": averages,  # the last window's, returned
        }

    saved = None if checkpoints is None else checkpoints.resume()
    if saved is not None:
        start, sums, count = saved["done"], dict(saved["sums"]), saved["count"]
        averages = dict(saved["averages"])
        loss_module.load_state_dict(saved["loss"])
        optimizer.load_state_dict(saved["optimizer"])
        if scheduler is not None:
            scheduler.load_state_dict(saved["scheduler"])
        if ema is not None:
            ema.load_state_dict(saved["ema"])
    bar = tqdm(
        range(start, num_updates),
        desc=desc,
        disable=not progress,
        leave=False,
        initial=start,
        total=num_updates,
    )
    for update in bar:
        out = loss_module(sample())
        loss = sum(value for key, value in out.items() if key.startswith("loss_"))
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if grad_clip is not None:
            torch.nn.utils.clip_grad_norm_(params, grad_clip)
        optimizer.step()
        if scheduler is not None:
            scheduler.step()
        if ema is not None:
            ema.update()
        for key, value in out.items():
            if value.numel() == 1:
                sums[key] = sums.get(key, 0.0) + value.detach()
        count += 1
        if count == log_every or update == num_updates - 1:
            averages = {key: float(total) / count for key, total in sums.items()}
            bar.set_postfix({k: f"{v:.4f}" for k, v in averages.items() if k.startswith("loss_")})
            if logger is not None:
                for key, value in averages.items():
                    logger.log_scalar(f"{log_prefix}{key}", value, step=step_offset + update + 1)
            sums, count = {}, 0
        if checkpoints is not None:
            checkpoints.after_update(update + 1, num_updates, loop_state)
    return averages
