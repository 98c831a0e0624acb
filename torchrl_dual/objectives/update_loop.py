"""The gradient-update loop shared by the training drivers, and a parameter EMA."""

from __future__ import annotations

from collections.abc import Callable

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
        torch._foreach_lerp_(self.shadow, [p.detach() for p in self.params], 1.0 - self.decay)

    @torch.no_grad()
    def copy_to(self, module: torch.nn.Module) -> None:
        """Writes the averages into ``module`` (the module the EMA was built on)."""
        for param, average in zip(module.parameters(), self.shadow, strict=True):
            param.copy_(average)


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
) -> dict[str, float]:
    """Runs ``num_updates`` gradient steps on the sum of the ``loss_*`` entries.

    Scalar entries of the loss output are averaged over each ``log_every`` window
    and sent to ``logger`` (a :class:`torchrl.record.loggers.Logger`) as
    ``{log_prefix}{name}``; the last window's averages are returned.

    Examples:
        >>> import torch
        >>> from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
        >>> from torchrl_dual.objectives import DiffusionPlannerLoss
        >>> from tensordict import TensorDict
        >>> model = TrajectoryDiffusion(TrajectoryLayout(2, 1, 3), hidden=16, depth=1)
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
    count = 0
    averages: dict[str, float] = {}
    bar = tqdm(range(num_updates), desc=desc, disable=not progress, leave=False)
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
    return averages
