"""TorchRL's generic ``LossModule`` checks, run on the package's losses.

pytorch/rl's ``test/objectives`` applies the same conventions to every TorchRL loss; they
are re-written here (TorchRL's test files are not installed) and run on each loss of
:data:`CASES`, with TorchRL's own ``IQLLoss``, ``CQLLoss`` and ``DiffusionBCLoss`` as
controls (a check the controls fail would not be TorchRL's convention):

* every ``loss_*`` entry is a differentiable term (``.backward()`` on each works;
  TorchRL's ``Trainer`` sums them), every other entry is a detached metric;
* the input tensordict's entries are unchanged (new entries may be written);
* ``reset_parameters_recursive()`` re-initialises the weights the loss owns, and neither
  its buffers (statistics, a frozen teacher) nor the modules it only reads;
* ``loss.double()`` (and ``loss.to("cuda")`` on a GPU) carries every tensor the loss
  reads: its forward never touches a tensor left behind by the cast;
* keys renamed with ``set_keys`` (and networks reading the renamed entries) give the same
  loss as the default keys;
* ``set_vmap_randomness`` works on the losses that ``vmap`` an ensemble;
* a ``state_dict`` saved and loaded into another instance gives the same loss;
* ``reduction="none"`` gives per-sample terms whose mean is the ``"mean"`` reduction.

A new loss joins by a factory in :data:`CASES`: ``make(keys) -> Case``, building the
loss, a batch and the modules it reads without owning them, its networks reading and the
loss's ``set_keys`` naming ``keys["observation"]`` and ``keys["action"]``.
"""

from __future__ import annotations

import copy
import io
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torch.overrides import TorchFunctionMode
from torch.utils._pytree import tree_flatten
from torchrl.data import Bounded
from torchrl.modules import MLP, DiffusionActor, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import CQLLoss, DiffusionBCLoss, IQLLoss, LossModule

from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.objectives import (
    CalQLLoss,
    DensityRatioLoss,
    DiffusionPlannerLoss,
    DistillationLoss,
    DUALLoss,
    IQLCriticLoss,
    SO2QLoss,
    WeightedMAPActorLoss,
    make_density_ratio_network,
)
from torchrl_dual.objectives.diffql_actor_loss import DiffQLActorLoss

OBS, ACT, B, H = 3, 2, 6, 3
RENAMED = {"observation": "state", "action": "act"}
SPEC = Bounded(-1.0, 1.0, shape=(ACT,))


@dataclass
class Case:
    """One loss under test.

    Attributes:
        loss: the loss module.
        batch: an input it accepts.
        reads: modules the loss reads but does not own (cast along with it, never reset).
        vmaps: whether the loss ``vmap``s an ensemble (``vmap_randomness`` applies).
    """

    loss: LossModule
    batch: TensorDict
    reads: tuple[nn.Module, ...] = ()
    vmaps: bool = False


# ----------------------------------------------------------------------------- builders
def _keys(keys: Mapping[str, str]) -> tuple[str, str]:
    return keys.get("observation", "observation"), keys.get("action", "action")


def _transitions(keys: Mapping[str, str], **extra: torch.Tensor) -> TensorDict:
    obs, act = _keys(keys)
    return TensorDict(
        {
            obs: torch.randn(B, OBS),
            act: torch.rand(B, ACT) * 2 - 1,
            "next": {
                obs: torch.randn(B, OBS),
                "reward": torch.randn(B, 1),
                "done": torch.zeros(B, 1, dtype=torch.bool),
                "terminated": torch.zeros(B, 1, dtype=torch.bool),
            },
            **extra,
        },
        batch_size=[B],
    )


def _windows(keys: Mapping[str, str]) -> TensorDict:
    obs, act = _keys(keys)
    return TensorDict(
        {obs: torch.randn(B, H + 1, OBS) * 2 + 1, act: torch.rand(B, H + 1, ACT) * 2 - 1},
        batch_size=[B, H + 1],
    )


def _tanh_normal(keys: Mapping[str, str], **kwargs) -> ProbabilisticActor:
    obs, act = _keys(keys)
    net = nn.Sequential(MLP(in_features=OBS, out_features=2 * ACT, num_cells=[8]),
                        NormalParamExtractor())  # fmt: skip
    return ProbabilisticActor(
        TensorDictModule(net, in_keys=[obs], out_keys=["loc", "scale"]),
        in_keys=["loc", "scale"], out_keys=[act], distribution_class=TanhNormal,
        spec=SPEC, **kwargs,
    )  # fmt: skip


def _q(keys: Mapping[str, str]) -> ValueOperator:
    return ValueOperator(MLP(in_features=OBS + ACT, out_features=1, num_cells=[8]),
                         in_keys=list(_keys(keys)), out_keys=["state_action_value"])  # fmt: skip


def _value(keys: Mapping[str, str]) -> ValueOperator:
    return ValueOperator(MLP(in_features=OBS, out_features=1, num_cells=[8]),
                         in_keys=[_keys(keys)[0]])  # fmt: skip


def _iql(keys: Mapping[str, str]) -> IQLLoss:
    loss = IQLLoss(_tanh_normal(keys), _q(keys), _value(keys), num_qvalue_nets=2)
    loss.set_keys(action=_keys(keys)[1])
    return loss


def _planner(num_steps: int) -> TrajectoryDiffusion:
    model = TrajectoryDiffusion(TrajectoryLayout(OBS, ACT, H), num_steps=num_steps, hidden=16,
                                depth=1)  # fmt: skip
    model.normalizer.fit(torch.randn(64, OBS) * 2 + 1, torch.rand(64, ACT) * 2 - 1)
    return model


def _diffusion_actor(keys: Mapping[str, str]) -> DiffusionActor:
    obs, act = _keys(keys)
    score = nn.Sequential(nn.Linear(ACT + OBS + 1, 16), nn.SiLU(), nn.Linear(16, ACT))
    return DiffusionActor(ACT, score_network=score, num_steps=3, in_keys=[obs], out_keys=[act])


# ----------------------------------------------------------------------------- factories
def make_iql(keys: Mapping[str, str]) -> Case:
    return Case(_iql(keys), _transitions(keys), vmaps=True)


def make_cql(keys: Mapping[str, str]) -> Case:
    loss = CQLLoss(
        _tanh_normal(keys, return_log_prob=True), _q(keys), num_random=2, action_spec=SPEC
    )
    loss.set_keys(action=_keys(keys)[1])
    return Case(loss, _transitions(keys), vmaps=True)


def make_diffusion_bc(keys: Mapping[str, str]) -> Case:
    loss = DiffusionBCLoss(_diffusion_actor(keys))
    loss.set_keys(**{k: v for k, v in keys.items() if k in ("observation", "action")})
    return Case(loss, _transitions(keys))


def make_planner(keys: Mapping[str, str]) -> Case:
    loss = DiffusionPlannerLoss(_planner(4))
    loss.set_keys(**keys)
    return Case(loss, _windows(keys))


def make_distillation(keys: Mapping[str, str]) -> Case:
    teacher = _planner(4)
    student = copy.deepcopy(teacher)
    student.num_steps = 2
    loss = DistillationLoss(student, teacher)
    loss.set_keys(**keys)
    return Case(loss, _windows(keys))


def make_diffql(keys: Mapping[str, str]) -> Case:
    critic = _iql(keys)
    loss = DiffQLActorLoss.from_iql(_diffusion_actor(keys), critic, lambda a: a.clamp(-1, 1),
                                    eta=1.0)  # fmt: skip
    loss.set_keys(**keys)
    return Case(loss, _transitions(keys), reads=(critic,))


def make_so2(keys: Mapping[str, str]) -> Case:
    actor = _tanh_normal(keys, return_log_prob=True)
    loss = SO2QLoss(actor, _q(keys), action_spec=SPEC,
                    num_qvalue_nets=3, entropy_coef=0.2)  # fmt: skip
    loss.set_keys(**keys, log_prob=f"{_keys(keys)[1]}_log_prob")
    return Case(loss, _transitions(keys), reads=(actor,), vmaps=True)


def make_calql(keys: Mapping[str, str]) -> Case:
    loss = CalQLLoss(
        _tanh_normal(keys, return_log_prob=True), _q(keys), num_random=2, action_spec=SPEC
    )
    loss.set_keys(action=_keys(keys)[1])
    batch = _transitions(keys, mc_return=torch.randn(B, 1))
    return Case(loss, batch, vmaps=True)


def _linear_head_actor() -> LinearHeadActor:
    return LinearHeadActor(MLP(in_features=OBS, out_features=ACT, num_cells=[8]), ACT)


def _iql_critic(keys: Mapping[str, str]) -> IQLCriticLoss:
    critic = IQLCriticLoss(_q(keys), _value(keys), loss_function="l2", expectile=0.7)
    critic.set_keys(action=_keys(keys)[1])
    return critic


def make_weighted_map(keys: Mapping[str, str]) -> Case:
    critic = _iql_critic(keys)
    loss = WeightedMAPActorLoss.from_iql(_linear_head_actor(), critic)
    loss.set_keys(**keys)
    return Case(loss, _transitions(keys), reads=(critic,), vmaps=True)


def make_dual(keys: Mapping[str, str]) -> Case:
    loss = DUALLoss(_linear_head_actor(), _iql_critic(keys))
    loss.set_keys(**keys)
    loss.make_value_estimator(gamma=0.99)
    return Case(loss, _transitions(keys), vmaps=True)


def make_density_ratio(keys: Mapping[str, str]) -> Case:
    network = make_density_ratio_network(OBS, ACT, num_cells=(8,), in_keys=_keys(keys))
    online = torch.arange(B) % 2 == 0
    return Case(DensityRatioLoss(network), _transitions(keys, online=online))


CONTROLS: dict[str, Callable[[Mapping[str, str]], Case]] = {
    "torchrl_iql": make_iql,
    "torchrl_cql": make_cql,
    "torchrl_diffusion_bc": make_diffusion_bc,
}
CASES: dict[str, Callable[[Mapping[str, str]], Case]] = {
    **CONTROLS,
    "diffusion_planner": make_planner,
    "distillation": make_distillation,
    "diffql_actor": make_diffql,
    "so2": make_so2,
    "calql": make_calql,
    "density_ratio": make_density_ratio,
    "weighted_map_actor": make_weighted_map,
    "dual": make_dual,
}


def build(name: str, keys: Mapping[str, str] | None = None, seed: int = 0) -> Case:
    torch.manual_seed(seed)
    return CASES[name](keys or {})


def forward(case: Case, seed: int = 1) -> TensorDictBase:
    torch.manual_seed(seed)
    return case.loss(case.batch.clone())


def loss_terms(out: TensorDictBase) -> dict[str, torch.Tensor]:
    return {k: v for k, v in out.items() if isinstance(k, str) and k.startswith("loss_")}


def floating_state(module: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in module.state_dict().items() if v.is_floating_point()}


# ----------------------------------------------------------------------------- checks
@pytest.mark.parametrize("name", CASES)
def test_loss_entries_are_differentiable_terms_and_the_rest_are_metrics(name):
    case = build(name)
    out = forward(case)
    terms = loss_terms(out)
    assert terms, f"{name} returns no loss_* entry"
    for key, value in out.items(True, True):
        if key in terms:
            assert value.requires_grad, f"{name}: {key} is detached; name a metric otherwise"
        else:
            assert not value.requires_grad, f"{name}: metric {key} carries a graph"
    for value in terms.values():  # each term alone, as TorchRL's per-term .backward()
        value.sum().backward(retain_graph=True)


@pytest.mark.parametrize("name", CASES)
def test_forward_leaves_the_input_entries_unchanged(name):
    case = build(name)
    before = case.batch.clone()
    torch.manual_seed(1)
    case.loss(case.batch)
    for key, value in before.items(True, True):
        assert torch.equal(case.batch.get(key), value), f"{name} modified {key}"


@pytest.mark.parametrize("name", CASES)
def test_reset_parameters_recursive_resets_what_the_loss_owns_only(name):
    case = build(name)
    owned = {
        k: p for k, p in case.loss.named_parameters() if p.dim() >= 1
    }  # TorchRL's scalars (log α) are not re-initialised by its losses either
    owned.update(
        (k, b)
        for k, b in case.loss.named_buffers()
        if k.startswith("target_") and "_params." in k and b.is_floating_point()
    )  # target networks: TorchRL resets them with their online networks
    with torch.no_grad():
        for value in owned.values():
            value.add_(1000.0)
    shifted = {k: v.detach().clone() for k, v in owned.items()}
    state = {k: v.clone() for k, v in case.loss.named_buffers() if k not in owned}
    read = [floating_state(module) for module in case.reads]
    case.loss.reset_parameters_recursive()
    kept = [k for k, v in owned.items() if torch.equal(v, shifted[k])]
    assert not kept, f"{name}: reset_parameters_recursive left {kept} as they were"
    buffers = dict(case.loss.named_buffers())  # statistics, a frozen teacher: not weights
    changed = [k for k, v in state.items() if not torch.equal(buffers[k], v)]
    assert not changed, f"{name}: reset_parameters_recursive changed the buffers {changed}"
    for module, before in zip(case.reads, read, strict=True):
        after = floating_state(module)
        changed = [k for k in before if not torch.equal(before[k], after[k])]
        assert not changed, f"{name}: reset re-initialised {changed} of a module it only reads"


class _StaleReads(TorchFunctionMode):
    """Records the ops whose inputs share storage with tensors a cast left behind, but
    ``requires_grad``, which ``TensorDict.to_module`` reads on the module's own tensors it
    swaps out (a functional module's own weights are never cast, in TorchRL's losses too)."""

    def __init__(self, stale: set[int]) -> None:
        super().__init__()
        self.stale, self.hits = stale, []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        if getattr(getattr(func, "__self__", None), "__name__", None) == "requires_grad":
            return func(*args, **(kwargs or {}))
        for leaf in tree_flatten((args, kwargs or {}))[0]:
            if isinstance(leaf, torch.Tensor):
                try:
                    pointer = leaf.untyped_storage().data_ptr()
                except (RuntimeError, NotImplementedError):  # a functorch wrapper
                    continue
                if pointer in self.stale:
                    self.hits.append(getattr(func, "__name__", str(func)))
        return func(*args, **(kwargs or {}))


def _storages(modules, functional: bool = True) -> dict[int, torch.Tensor]:
    """Every floating tensor held by ``modules`` and their submodules (and, with
    ``functional``, by the functional modules a loss keeps in its ``__dict__``), by storage
    address (held, so that no new tensor reuses an address while the check runs)."""
    found, seen = {}, set()
    stack = list(modules)
    while stack:
        module = stack.pop()
        if id(module) in seen:
            continue
        seen.add(id(module))
        for t in [*module.parameters(recurse=False), *module.buffers(recurse=False)]:
            if t.is_floating_point():
                found[t.untyped_storage().data_ptr()] = t.detach()
        stack += list(module.children())
        if functional:
            stack += [v for v in vars(module).values() if isinstance(v, nn.Module)]
    return found


def _moved(case: Case, move: Callable) -> tuple[TensorDictBase, list[str]]:
    """``case``'s loss, the modules it reads and its batch moved by ``move``, and its
    forward's output and the ops that read a tensor the move left behind."""
    before = _storages([case.loss, *case.reads])
    num_parameters = len(list(case.loss.parameters()))
    case.loss = move(case.loss)
    # a parameter shared by two of the loss's modules stays one parameter
    assert len(list(case.loss.parameters())) == num_parameters
    for module in case.reads:
        move(module)
    device = next(iter(case.loss.parameters())).device
    batch = case.batch.apply(lambda t: move(t) if t.is_floating_point() else t.to(device))
    carried = _storages([case.loss, *case.reads], functional=False)  # what .to() moves
    left_behind = set(before) - set(carried)
    mode = _StaleReads(left_behind)
    torch.manual_seed(1)
    with mode:
        out = case.loss(batch)
    del before
    return out, mode.hits


@pytest.mark.parametrize("name", CASES)
def test_a_cast_carries_every_tensor_the_loss_reads(name):
    case = build(name)
    out, stale = _moved(case, lambda x: x.double())
    assert not stale, f"{name} read tensors the cast left behind in {sorted(set(stale))}"
    for key, value in loss_terms(out).items():
        assert value.dtype == torch.float64 and torch.isfinite(value).all(), (key, value)


class _ReadsItsModuleDirectly(LossModule):
    """A loss that reads a buffer of its functional module outside ``to_module``: the
    mistake the cast check is there to catch (``x * scale`` promotes silently)."""

    net: nn.Module
    net_params: TensorDictBase
    target_net_params: TensorDictBase

    def __init__(self) -> None:
        super().__init__()
        net = nn.Linear(OBS, 1)
        net.register_buffer("scale", torch.full((1,), 2.0))
        self.convert_to_functional(net, "net")

    def forward(self, td: TensorDictBase) -> TensorDict:
        with self.net_params.to_module(self.net):
            value = self.net(td["observation"])
        return TensorDict(loss_value=(value * self.net.scale).mean())


def test_the_cast_check_catches_a_tensor_left_behind():
    case = Case(_ReadsItsModuleDirectly(), _transitions({}))
    out, stale = _moved(case, lambda x: x.double())
    assert out["loss_value"].dtype == torch.float64 and stale == ["mul"]


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
@pytest.mark.parametrize("name", CASES)
def test_a_device_move_carries_every_tensor_the_loss_reads(name):
    case = build(name)
    out, stale = _moved(case, lambda x: x.to("cuda"))
    assert not stale, f"{name} read tensors the move left behind in {sorted(set(stale))}"
    for key, value in loss_terms(out).items():
        assert value.device.type == "cuda" and torch.isfinite(value).all(), (key, value)


@pytest.mark.parametrize("name", CASES)
def test_renamed_keys_reach_every_network(name):
    default, renamed = build(name), build(name, RENAMED)
    expected, got = loss_terms(forward(default)), loss_terms(forward(renamed))
    assert expected.keys() == got.keys()
    for key in expected:
        torch.testing.assert_close(got[key], expected[key], rtol=0, atol=0)


@pytest.mark.parametrize("name", [n for n in CASES if build(n).vmaps])
@pytest.mark.parametrize("randomness", ["same", "different", "error"])
def test_vmap_randomness_is_settable(name, randomness):
    case = build(name)
    case.loss.set_vmap_randomness(randomness)
    assert case.loss.vmap_randomness == randomness
    assert all(torch.isfinite(v).all() for v in loss_terms(forward(case)).values())


@pytest.mark.parametrize("name", CASES)
def test_a_state_dict_round_trip_gives_the_same_loss(name):
    source, target = build(name, seed=0), build(name, seed=1)
    for src, dst in zip((source.loss, *source.reads), (target.loss, *target.reads), strict=True):
        buffer = io.BytesIO()
        torch.save(src.state_dict(), buffer)
        buffer.seek(0)
        dst.load_state_dict(torch.load(buffer, weights_only=True))
    target.batch = source.batch
    expected, got = loss_terms(forward(source)), loss_terms(forward(target))
    for key in expected:
        torch.testing.assert_close(got[key], expected[key], rtol=0, atol=0)


@pytest.mark.parametrize("name", CASES)
def test_reduction_none_gives_terms_whose_mean_is_the_mean_reduction(name):
    case = build(name)
    mean = loss_terms(forward(case))
    case.loss.reduction = "none"
    none = loss_terms(forward(case))
    for key, value in mean.items():
        assert value.shape == (), (key, value.shape)
        torch.testing.assert_close(none[key].mean(), value, msg=key)
