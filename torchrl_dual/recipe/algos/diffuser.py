"""The ``diffuser`` baseline: the undistilled trajectory planner acting with all N steps.

The paper's Diffuser baseline (Appendix, "Diffuser"; Janner et al. 2022, without its
return guide) pre-trains the diffusion planner on ``D_offline`` with ``L_VLB`` (Eq. 3),
acts with its first planned action ``a = τ_{a_0}`` (Eq. 5) and fine-tunes it with
``L_VLB`` on ``D_offline ∪ D_online``. The paper samples it with ``N = 20`` steps; our
planner's steps are a power of 2 (distillation halves them), so it acts with the
teacher itself, ``N = planner.num_steps = 32`` (no distillation, no Laplace, no critic).

* acting: :class:`~torchrl_dual.modules.PlannerPolicy` over the ``N``-step teacher;
  under random exploration the latent is drawn (``τ^N ~ N(0, I)``) and sampled with
  ``diffuser.sampler`` (DDIM: the plan's only randomness is the latent; DDPM: fresh noise
  at every step). There is no ``σ̄``: the exploration is the planner's own randomness.
  Evaluation: the deterministic DDIM plan of the zero latent.
* online update: one ``L_VLB`` step per update on ``planner.batch_size`` windows, a share
  ``online.offline_fraction`` of them from ``D_offline``, the rest from the online
  episodes (all from ``D_offline`` until an online episode holds ``H + 1`` steps). The
  transition batch the run draws is not used: the planner learns from windows.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from torchrl_dual.diffusion import WindowReplayBuffer
from torchrl_dual.modules import PlannerPolicy
from torchrl_dual.objectives import DiffusionPlannerLoss
from torchrl_dual.objectives.optim import adam
from torchrl_dual.objectives.update_loop import run_updates
from torchrl_dual.recipe.kits.build import projected_policy
from torchrl_dual.recipe.o2o.learner import Learner, RunContext
from torchrl_dual.recipe.parts import networks
from torchrl_dual.recipe.parts.planner_stage import offline_windows


class DiffuserLearner(Learner):
    """The ``N``-step planner: ``L_VLB`` offline, acts with ``τ_{a_0}``, ``L_VLB`` online."""

    title = "Diffuser"
    shared_stages = ("planner",)  # offline_cache: shared by every online shift
    online_keys = ("diffuser.sampler",)

    def __init__(self, run: RunContext) -> None:
        self.run = run
        settings = self.settings = run.settings
        p = settings.planner
        self.offline_windows = offline_windows(settings, run.data, p.batch_size)
        self.online_windows: WindowReplayBuffer | None = None
        self.online_length = 0
        self.planner = networks.make_planner(p, run.data, settings.device)
        self.loss = DiffusionPlannerLoss(
            self.planner, action_condition_prob=p.action_condition_prob
        )
        self.optimizer = adam(self.loss.parameters(), lr=p.lr)
        space = run.env.action_spec.space
        policy = PlannerPolicy(
            self.planner,
            sampler=settings.diffuser.sampler,
            action_low=space.low.to(settings.device),
            action_high=space.high.to(settings.device),
        )
        self.evaluation_policy = policy  # the zero-latent DDIM plan under DETERMINISTIC
        self.exploration_policy = projected_policy(settings, policy)

    def modules(self) -> dict:
        """The planner and its optimizer."""
        return {"planner": self.planner, "planner_optimizer": self.optimizer}

    def offline_stages(self) -> list:
        """One offline stage: the planner's pre-training (Eq. 3)."""
        return [("planner", self.pretrain_planner)]

    def pretrain_planner(self) -> None:
        """Pre-trains the planner on ``D_offline`` windows (Eq. 3), checkpointed within the stage.

        ``budget.planner_updates`` ``L_VLB`` steps.
        """
        with self.run.stage_checkpoints() as checkpoints:
            run_updates(
                self.loss,
                self.offline_windows.sample,
                self.settings.budget.planner_updates,
                self.optimizer,
                desc="planner",
                logger=self.run.logger,
                log_prefix="planner/",
                progress=self.settings.progress,
                checkpoints=checkpoints,
            )

    def windows(self) -> TensorDictBase:
        """``planner.batch_size`` windows, ``online.offline_fraction`` of them offline."""
        self.refresh_online_windows()
        batch = self.offline_windows.sample()
        if self.online_windows is None:
            return batch
        offline = round(self.settings.online.offline_fraction * batch.shape[0])
        online = self.online_windows.sample()[: batch.shape[0] - offline]
        keys = ("observation", "action")
        return torch.cat([batch[:offline].select(*keys), online.select(*keys)], 0)

    def refresh_online_windows(self) -> None:
        """Rebuilds the online windows when ``D_online`` has grown (once per collected batch)."""
        online = self.run.replay.online_buffer
        if len(online) == self.online_length:
            return
        self.online_length = len(online)
        p = self.settings.planner
        try:
            self.online_windows = WindowReplayBuffer(
                online[: len(online)], p.horizon, p.batch_size, device=self.settings.device
            )
        except ValueError:  # no online episode holds H + 1 steps yet
            self.online_windows = None

    def update(self, batch: TensorDictBase) -> dict:
        """One ``L_VLB`` step on :meth:`windows` (the transition ``batch`` is not used)."""
        out = self.loss(self.windows())
        self.optimizer.zero_grad(set_to_none=True)
        out["loss_diffusion"].backward()
        torch.nn.utils.clip_grad_norm_(self.loss.parameters(), 1.0)
        self.optimizer.step()
        return {k: v.detach() for k, v in out.items()}
