"""The planner's offline stage, shared by every learner that trains the trajectory planner.

``dual``, ``diffuser``, ``edis``: its window buffer, the ``L_VLB`` pre-training on
``D_offline`` (Eq. 3, Algorithm 1 lines 3-4) and the check that a window fits an episode.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from torchrl_dual.data import OfflineDataset
from torchrl_dual.diffusion import TrajectoryDiffusion, WindowReplayBuffer
from torchrl_dual.objectives import train_planner
from torchrl_dual.recipe.settings.errors import UserError
from torchrl_dual.recipe.settings.structured import RecipeSettings

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.learner import RunContext


def offline_windows(
    settings: RecipeSettings, data: OfflineDataset, batch_size: int
) -> WindowReplayBuffer:
    """``batch_size`` windows of ``planner.horizon + 1`` steps per draw from ``D_offline``.

    A :class:`UserError` on ``planner.horizon`` if no episode is long enough.
    """
    try:
        return WindowReplayBuffer(
            data.transitions, settings.planner.horizon, batch_size, device=settings.device
        )
    except ValueError as err:  # no episode is long enough for a window
        raise UserError("planner.horizon", settings.planner.horizon, str(err)) from err


def pretrain_planner(
    run: RunContext, planner: TrajectoryDiffusion, windows: WindowReplayBuffer
) -> None:
    """Pre-trains the planner on ``D_offline`` windows (Eq. 3), checkpointed within the stage.

    ``budget.planner_updates`` ``L_VLB`` steps with the ``planner.*`` learning rate and
    ``a_0``-conditioning probability; logs ``planner/``; checkpointed through
    ``run.stage_checkpoints``.
    """
    settings = run.settings
    with run.stage_checkpoints() as checkpoints:
        train_planner(
            planner,
            windows.sample,
            settings.budget.planner_updates,
            lr=settings.planner.lr,
            action_condition_prob=settings.planner.action_condition_prob,
            logger=run.logger,
            log_prefix="planner/",
            progress=settings.progress,
            checkpoints=checkpoints,
        )
