"""TorchRL conventions the package's losses follow (issue 30 item 6)."""

from __future__ import annotations

import copy
import sys
from pathlib import Path

import pytest
import torch
from torchrl.modules import MLP, ValueOperator

from torchrl_dual import DiffusionPlannerLoss, DistillationLoss, PlannerActor, WeightedMAPActorLoss

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_compile import _iql_critic, _planner, _transitions, _windows  # noqa: E402


@pytest.mark.parametrize("reduction", ["none", "mean", "sum"])
def test_reduction_none_gives_one_loss_per_sample(reduction):
    """Windows ``[B, H + 1]``: one loss per window ``[B]``; transitions ``[B]``: ``[B]``."""
    teacher = _planner(4)
    student = copy.deepcopy(teacher)
    student.num_steps = 2
    actor = PlannerActor(_planner(1))
    cases = [
        (DiffusionPlannerLoss(_planner(4), reduction=reduction), _windows(), "loss_diffusion"),
        (DistillationLoss(student, teacher, reduction=reduction), _windows(), "loss_distillation"),
        (
            WeightedMAPActorLoss.from_iql(actor, _iql_critic(), reduction=reduction),
            _transitions(),
            "loss_actor",
        ),
    ]
    for loss_fn, batch, key in cases:
        torch.manual_seed(0)
        value = loss_fn(batch)[key]
        assert value.shape == ((8,) if reduction == "none" else ()), (key, value.shape)
        if reduction == "none":
            torch.manual_seed(0)
            loss_fn.reduction = "mean"
            torch.testing.assert_close(loss_fn(batch)[key], value.mean())


def test_a_dropout_critic_works_with_the_iql_weighted_actor_loss():
    """``vmap_randomness``: TorchRL's rule ("different" when a critic holds dropout) reaches
    the vmapped twin-Q evaluation; settable as on any TorchRL loss."""
    from tensordict.nn import TensorDictModule
    from test_compile import _NoActor
    from torchrl.modules import ProbabilisticActor
    from torchrl.objectives import IQLLoss

    stand_in = ProbabilisticActor(
        TensorDictModule(_NoActor(), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], distribution_class=torch.distributions.Normal,
    )  # fmt: skip
    dropout_q = ValueOperator(
        MLP(in_features=7, out_features=1, num_cells=[16, 16], dropout=0.1),
        in_keys=["observation", "action"],
    )
    value = ValueOperator(
        MLP(in_features=5, out_features=1, num_cells=[16]), in_keys=["observation"]
    )
    critic = IQLLoss(stand_in, dropout_q, value, num_qvalue_nets=2)
    loss = WeightedMAPActorLoss.from_iql(PlannerActor(_planner(1)), critic, weighting="advantage")
    assert loss.vmap_randomness == "different"
    assert torch.isfinite(loss(_transitions())["loss_actor"])
    loss.set_vmap_randomness("same")
    assert torch.isfinite(loss(_transitions())["loss_actor"])
