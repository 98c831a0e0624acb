"""The hot path compiles whole and never reads a device value back to the host.

``torch.compile(fullgraph=True)`` (Dynamo with the ``eager`` backend: the graph-break
check, without code generation) of the forward of DUAL's three losses and of its acting
policy in both exploration modes (DETERMINISTIC and RANDOM), on the CPU, and a
``TorchDispatchMode`` that counts the ops which copy a device value to the host
(``aten._local_scalar_dense``: ``.item()``, ``bool(t)``, ``int(t)``; ``nonzero``) during an
update's forward and backward and during an acting step.
"""

from __future__ import annotations

import collections
import copy

import pytest
import torch
from tensordict import TensorDict
from torch.utils._python_dispatch import TorchDispatchMode
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, ValueOperator
from torchrl.objectives import IQLLoss

import torchrl_dual._utils as utils
from torchrl_dual import (
    DiffusionPlannerLoss,
    DistillationLoss,
    LinearHeadActor,
    PlannerActor,
    TransitionModel,
    WeightedMAPActorLoss,
    make_dual_policy,
)
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.recipe.algos.iql import make_iql_actor

OBS, ACT, H = 5, 2, 4
HOST_READS = {
    torch.ops.aten._local_scalar_dense.default,
    torch.ops.aten.nonzero.default,
    torch.ops.aten.is_nonzero.default,
}


class HostReads(TorchDispatchMode):
    """Counts the dispatched ops that read a tensor's value back to the host."""

    def __init__(self) -> None:
        super().__init__()
        self.count = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func in HOST_READS:
            self.count[str(func)] += 1
        return func(*args, **(kwargs or {}))


def _planner(steps: int) -> TrajectoryDiffusion:
    torch.manual_seed(0)
    model = TrajectoryDiffusion(TrajectoryLayout(OBS, ACT, H), num_steps=steps, hidden=16, depth=1)
    model.normalizer.fit(torch.randn(64, OBS) * 2 + 1, torch.rand(64, ACT) * 2 - 1)
    return model


def _windows() -> TensorDict:
    return TensorDict(
        observation=torch.randn(8, H + 1, OBS), action=torch.rand(8, H + 1, ACT) * 2 - 1,
        batch_size=[8, H + 1],
    )  # fmt: skip


def _transitions() -> TensorDict:
    return TensorDict(
        observation=torch.randn(8, OBS),
        action=torch.rand(8, ACT) * 2 - 1,
        next=TensorDict(
            observation=torch.randn(8, OBS), reward=torch.randn(8, 1),
            done=torch.zeros(8, 1, dtype=torch.bool),
            terminated=torch.zeros(8, 1, dtype=torch.bool), batch_size=[8],
        ),
        batch_size=[8],
    )  # fmt: skip


class _NoActor(torch.nn.Module):
    def forward(self, observation):
        raise RuntimeError("unused")


def _iql_critic() -> IQLLoss:
    from tensordict.nn import TensorDictModule

    def mlp(inputs):
        return MLP(in_features=inputs, out_features=1, num_cells=[16, 16])

    actor = ProbabilisticActor(
        TensorDictModule(_NoActor(), in_keys=["observation"], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], distribution_class=torch.distributions.Normal,
    )  # fmt: skip
    return IQLLoss(
        actor, ValueOperator(mlp(OBS + ACT), in_keys=["observation", "action"]),
        ValueOperator(mlp(OBS), in_keys=["observation"]), num_qvalue_nets=2,
    )  # fmt: skip


def _losses() -> dict[str, tuple[torch.nn.Module, TensorDict, str]]:
    teacher = _planner(4)
    student = copy.deepcopy(teacher)
    student.num_steps = 2
    actor = PlannerActor(_planner(1))
    return {
        "planner": (DiffusionPlannerLoss(_planner(4)), _windows(), "loss_diffusion"),
        "distillation": (DistillationLoss(student, teacher), _windows(), "loss_distillation"),
        "actor": (
            WeightedMAPActorLoss.from_iql(actor, _iql_critic(), weighting="advantage"),
            _transitions(),
            "loss_actor",
        ),
    }


def _policies() -> dict[str, torch.nn.Module]:
    spec = Bounded(-1.0, 1.0, shape=(ACT,))
    model = _planner(1)
    dual = make_dual_policy(
        PlannerActor(model), spec, transition_model=TransitionModel.frozen_copy(model)
    )
    fit = [TensorDict(observation=torch.randn(64, OBS), batch_size=[64])]
    dual[0].fit_laplace(fit)
    iql_actor = make_iql_actor(
        _cfg(), OBS, spec, distribution="gaussian"
    )  # iql_la's: the Gauss-Newton posterior
    iql_la = make_dual_policy(LinearHeadActor.from_actor(iql_actor), spec, shift_weight=0.0)
    iql_la[0].fit_laplace(fit)
    return {"dual": dual, "iql_la": iql_la}


def _cfg():
    from torchrl_dual.recipe.settings.baselines import MLPActorSettings

    return MLPActorSettings(hidden=16, depth=2, lr=3e-4)


def _step() -> TensorDict:
    obs = torch.randn(3, OBS)
    return TensorDict(
        observation=obs, previous_observation=obs + 0.1, previous_action=torch.zeros(3, ACT),
        previous_valid=torch.ones(3, 1, dtype=torch.bool), batch_size=[3],
    )  # fmt: skip


@pytest.mark.parametrize("name", ["planner", "distillation", "actor"])
def test_each_loss_compiles_without_a_graph_break(name):
    loss_fn, batch, key = _losses()[name]
    torch._dynamo.reset()
    out = torch.compile(loss_fn, fullgraph=True, backend="eager")(batch)
    assert torch.isfinite(out[key])


@pytest.mark.parametrize("mode", [ExplorationType.DETERMINISTIC, ExplorationType.RANDOM])
@pytest.mark.parametrize("name", ["dual", "iql_la"])
def test_the_acting_policy_compiles_without_a_graph_break_and_acts_alike(name, mode):
    """DETERMINISTIC as the evaluation acts, RANDOM as the collector acts (Eq. 9's
    ensemble draw and Eq. 10's noise: ``LaplaceEnsembleActor`` then ``ShiftAwareNoise``).
    The ``eager`` backend runs Dynamo's graph with the same ops in the same order, so under
    one seed the compiled policy draws the same noise as the eager one."""
    policy = _policies()[name]
    step = _step()

    def act(td):
        with set_exploration_type(mode):
            return policy(td)

    with torch.no_grad():
        act(step.clone())  # a collector's first step: caches and memos built eagerly
        torch.manual_seed(1)
        eager = act(step.clone())
        torch._dynamo.reset()
        compiled_act = torch.compile(act, fullgraph=True, backend="eager")
        torch.manual_seed(1)
        compiled = compiled_act(step.clone())
    for key in ("action", "loc", "scale", "exploration_scale"):
        torch.testing.assert_close(compiled[key], eager[key])
    if mode is ExplorationType.RANDOM:  # the noise is there: not the mean action
        assert not torch.allclose(compiled["action"], compiled["loc"].clamp(-1.0, 1.0))


def test_an_update_reads_nothing_back_to_the_host_once_checks_are_off(monkeypatch):
    """Forward and backward of each loss: 0 host reads. The NaN checks are the only host
    reads of the eager path; under ``torch.compile`` or a CUDA-graph capture they are
    skipped (``host_reads_allowed`` is then ``False``, as patched here)."""
    losses = _losses()
    for name, (loss_fn, batch, key) in losses.items():
        with HostReads() as reads:
            loss_fn(batch)[key].backward()
        # eager: the two inputs' NaN checks, and the actor's advantage weights'
        assert sum(reads.count.values()) == (3 if name == "actor" else 2), name
    monkeypatch.setattr(utils, "host_reads_allowed", lambda: False)
    for name, (loss_fn, batch, key) in losses.items():
        with HostReads() as reads:
            loss_fn(batch)[key].backward()
        assert not reads.count, (name, reads.count)


@pytest.mark.parametrize("name", ["dual", "iql_la"])
def test_an_acting_step_reads_nothing_back_to_the_host(name):
    policy = _policies()[name]
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        policy(_step())  # first call: caches and memos
        with HostReads() as reads:
            out = policy(_step())
    assert not reads.count, reads.count
    assert out["action"].shape == (3, ACT)


def test_nan_input_still_raises_on_the_default_eager_path():
    loss_fn, batch, _ = _losses()["actor"]
    batch["action"][0, 0] = float("nan")
    with pytest.raises(ValueError, match="action holds 1 NaN/inf entries"):
        loss_fn(batch)


def test_the_host_copies_follow_load_state_dict():
    """``num_steps``, ``fitted`` and ``λ > 0`` are read from host copies on the hot path;
    loading a state dict refreshes them."""
    four, one = _planner(4), _planner(1)
    one.load_state_dict(four.state_dict())
    assert one.num_steps == 4
    policies = _policies()
    fresh = make_dual_policy(
        PlannerActor(_planner(1)), Bounded(-1.0, 1.0, shape=(ACT,)), shift_weight=0.0,
        transition_model=TransitionModel.frozen_copy(_planner(1)),
    )  # fmt: skip
    assert not fresh[0].laplace.is_fitted and not fresh[1]._uses_shift
    fresh.load_state_dict(policies["dual"].state_dict())
    assert fresh[0].laplace.is_fitted and fresh[1]._uses_shift
