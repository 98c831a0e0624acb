"""The workloads ``gpu_throughput.py`` times, built at AntMaze's sizes with the recipe's
``algo=dual`` settings: one Adam step of the planner's loss (Eq. 3), of the first
distillation round (Eq. 4-5), of ``DualLearner.update``'s actor+critic update (IQL's Q and
V losses, then Eq. 7's actor loss), and DUAL's online policy (Eq. 9-10) with the batches
its posterior (Eq. 8) is fitted on.

Each ``build_*`` update builder returns ``(update, batch)``, the update a function of one
batch (its optimizers made ``capturable`` for CUDA graphs when asked).

Examples:
    >>> update, batch = build_planner(TINY, "cpu", capturable=False)
    >>> sorted(update(batch).keys())
    ['loss_diffusion', 'x0_error']
    >>> step_input(TINY, 3, "cpu")["observation"].shape
    torch.Size([3, 5])
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.data import Bounded
from torchrl.modules import MLP, ValueOperator
from torchrl.objectives import SoftUpdate

from torchrl_dual import (
    DiffusionPlannerLoss,
    DistillationLoss,
    PlannerActor,
    TransitionModel,
    make_dual_policy,
)
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.objectives import DUALLoss, IQLCriticLoss
from torchrl_dual.trainers import CriticActorStepper


@dataclass
class Sizes:
    """AntMaze U-maze's shapes and ``budget=paper``'s networks (``algo=dual``)."""

    obs_dim: int = 31
    action_dim: int = 8
    horizon: int = 8
    hidden: int = 256
    depth: int = 3  # planner denoiser blocks (critics and V: 2 layers, as critic/iql.yaml)
    batch: int = 256
    teacher_steps: int = 32
    laplace_transitions: int = 65536


TINY = Sizes(obs_dim=5, action_dim=2, horizon=4, hidden=16, depth=1, batch=8,
             teacher_steps=4, laplace_transitions=512)  # fmt: skip


# ----------------------------------------------------------------------------- builders
def _planner(s: Sizes, num_steps: int, device: str) -> TrajectoryDiffusion:
    layout = TrajectoryLayout(s.obs_dim, s.action_dim, s.horizon)
    model = TrajectoryDiffusion(layout, num_steps=num_steps, hidden=s.hidden, depth=s.depth)
    model.normalizer.fit(torch.randn(512, s.obs_dim), torch.rand(512, s.action_dim) * 2 - 1)
    return model.to(device)


def _windows(s: Sizes, device: str) -> TensorDict:
    rows = s.horizon + 1
    return TensorDict(
        observation=torch.randn(s.batch, rows, s.obs_dim, device=device),
        action=torch.rand(s.batch, rows, s.action_dim, device=device) * 2 - 1,
        batch_size=[s.batch, rows],
        device=device,
    )


def _transitions(s: Sizes, device: str) -> TensorDict:
    b = s.batch
    return TensorDict(
        observation=torch.randn(b, s.obs_dim, device=device),
        action=torch.rand(b, s.action_dim, device=device) * 2 - 1,
        next=TensorDict(
            observation=torch.randn(b, s.obs_dim, device=device),
            reward=torch.randn(b, 1, device=device),
            done=torch.zeros(b, 1, dtype=torch.bool, device=device),
            terminated=torch.zeros(b, 1, dtype=torch.bool, device=device),
            batch_size=[b],
        ),
        batch_size=[b],
        device=device,
    )


def _adam(params, capturable: bool) -> torch.optim.Adam:
    return torch.optim.Adam(params, lr=3e-4, capturable=capturable)


def _step(loss_fn: nn.Module, key: str, optimizer: torch.optim.Optimizer):
    def update(batch: TensorDict) -> TensorDict:
        out = loss_fn(batch)
        optimizer.zero_grad(set_to_none=True)
        out[key].backward()
        optimizer.step()
        return out.detach()

    return update


def build_planner(s: Sizes, device: str, capturable: bool):
    """One Adam step of Eq. 3 on a batch of ``H + 1``-row windows."""
    loss_fn = DiffusionPlannerLoss(_planner(s, s.teacher_steps, device))
    return _step(loss_fn, "loss_diffusion", _adam(loss_fn.parameters(), capturable)), _windows(
        s, device
    )


def build_distillation(s: Sizes, device: str, capturable: bool):
    """One Adam step of the first distillation round (N → N/2)."""
    teacher = _planner(s, s.teacher_steps, device)
    student = copy.deepcopy(teacher)
    student.num_steps = s.teacher_steps // 2
    loss_fn = DistillationLoss(student, teacher)
    optimizer = _adam(loss_fn.student_params.values(True, True), capturable)
    return _step(loss_fn, "loss_distillation", optimizer), _windows(s, device)


def build_actor_critic(s: Sizes, device: str, capturable: bool):
    """``DualLearner.update``: ``CriticActorStepper`` on ``DUALLoss``, IQL's Q + V step and
    soft update, then Eq. 7's actor step."""

    def mlp(inputs: int) -> MLP:
        return MLP(in_features=inputs, out_features=1, num_cells=[s.hidden] * 2,
                   activation_class=nn.ReLU)  # fmt: skip

    critic = IQLCriticLoss(
        ValueOperator(mlp(s.obs_dim + s.action_dim), in_keys=["observation", "action"]),
        ValueOperator(mlp(s.obs_dim), in_keys=["observation"]),
        expectile=0.9,
        loss_function="l2",
    )
    actor = PlannerActor(_planner(s, 1, device), init_std=0.3)
    loss = DUALLoss(actor, critic, temperature=10.0, max_weight=100.0).to(device)
    loss.make_value_estimator(gamma=0.99)
    stepper = CriticActorStepper(
        loss,
        _adam(loss.critic_parameters(), capturable),
        _adam(loss.actor_parameters(), capturable),
        target_update=SoftUpdate(loss, tau=0.005),
    )
    return stepper.update, _transitions(s, device)


def build_policy(s: Sizes, device: str):
    """DUAL's online policy (Eq. 9-10), its posterior fitted on random states."""
    model = _planner(s, 1, device)
    actor = PlannerActor(model, init_std=0.3)
    spec = Bounded(-1.0, 1.0, shape=(s.action_dim,), device=device)
    policy = make_dual_policy(
        actor, spec, transition_model=TransitionModel.frozen_copy(model), shift_weight=0.5,
        device=device,
    )  # fmt: skip
    return policy


def step_input(s: Sizes, batch: int, device: str) -> TensorDict:
    obs = torch.randn(batch, s.obs_dim, device=device)
    return TensorDict(
        observation=obs,
        previous_observation=obs + 0.1,
        previous_action=torch.zeros(batch, s.action_dim, device=device),
        previous_valid=torch.ones(batch, 1, dtype=torch.bool, device=device),
        batch_size=[batch],
        device=device,
    )


def fit_batches(s: Sizes, device: str, chunk: int = 4096) -> list[TensorDict]:
    n = s.laplace_transitions
    return [
        TensorDict(
            observation=torch.randn(min(chunk, n - i), s.obs_dim, device=device),
            batch_size=[min(chunk, n - i)],
        )  # fmt: skip
        for i in range(0, n, chunk)
    ]
