"""Which updates a CUDA graph may replay (``compile.cudagraphs``, issue 30 item 3).

This machine has no GPU, so the captures themselves cannot run here. What a capture needs
of an update is checked on the CPU instead, for every algorithm, offline and online:

1. **The same kernels every call.** After a first call (which makes the optimizers'
   state), each update dispatches the same ATen operations on tensors of the same shapes
   (a ``TorchDispatchMode`` trace): a replay runs exactly the captured ones.
2. **No Python state.** The update leaves every Python attribute reachable from the
   learner (counters, schedules, flags) as it was; per-update bookkeeping belongs to
   ``Learner.after_update``, which runs outside the graph.
3. **It reads its batch.** A graph's input is the batch copied into the captured one:
   with the same random draws, a different batch gives different losses.

Every algorithm whose ``ALGORITHMS`` entry allows CUDA graphs passes all three; each one
whose entry gives a reason (``no_cuda_graph``) fails at least one, so the reason is true.
"""

from __future__ import annotations

import copy
from typing import Any

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode

from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, ConfigError, O2ORun, compose_checked
from torchrl_dual.recipe.o2o.loop import online_batch
from torchrl_dual.recipe.o2o.update_step import (
    CUDA_GRAPH_WARMUP,
    GraphedUpdate,
    make_update_step,
)

TINY = (
    "budget=smoke", "env=frozenlake", "budget.dataset_transitions=1000",
    "budget.network_width=16", "budget.batch_size=32", "progress=false", "num_threads=1",
)  # fmt: skip
EXTRA = {"dacer": ("dacer.entropy_every=2",)}  # its Python schedule within UPDATES
UPDATES = 4  # per phase, after the first


class OpTrace(TorchDispatchMode):
    """The ATen operations dispatched, with the shapes of their tensor arguments."""

    def __init__(self) -> None:
        super().__init__()
        self.ops: list[tuple] = []

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        shapes = tuple(tuple(a.shape) for a in args if isinstance(a, torch.Tensor))
        self.ops.append((str(func), shapes))
        return func(*args, **(kwargs or {}))


def python_state(root: Any) -> dict[str, Any]:
    """Every int, float, bool, str and None reachable from ``root`` through plain objects,
    dicts, lists and tuples (not through modules, tensors or optimizers), by path."""
    out: dict[str, Any] = {}
    seen: set[int] = set()
    todo: list[tuple[str, Any]] = [("learner", root)]
    while todo:
        path, obj = todo.pop()
        if isinstance(obj, bool | int | float | str | type(None)):
            out[path] = obj
            continue
        skip = (torch.Tensor, torch.nn.Module, torch.optim.Optimizer, type)
        if id(obj) in seen or isinstance(obj, skip) or callable(obj) and not vars_of(obj):
            continue
        seen.add(id(obj))
        if isinstance(obj, dict):
            todo += [(f"{path}[{k!r}]", v) for k, v in obj.items()]
        elif isinstance(obj, list | tuple):
            todo += [(f"{path}[{i}]", v) for i, v in enumerate(obj)]
        else:
            todo += [(f"{path}.{k}", v) for k, v in vars_of(obj).items() if k != "run"]
    return out


def _same(a: Any, b: Any) -> bool:
    """Equal, NaN equal to NaN."""
    return a == b or isinstance(a, float) and isinstance(b, float) and a != a and b != b


def vars_of(obj: Any) -> dict[str, Any]:
    try:
        return vars(obj)
    except TypeError:
        return {}


def _run(algo: str, tmp_path, cache) -> O2ORun:
    cfg = compose_checked(
        CONFIG_DIR,
        [*TINY, *EXTRA.get(algo, ()), f"algo={algo}", f"output_dir={tmp_path}",
         f"data_cache_dir={cache}"],
    )  # fmt: skip
    return O2ORun(cfg, ALGORITHMS[algo].learner)


def _batch(run: O2ORun, online: bool):
    if not online:
        return run.offline_buffer.sample()
    k = run.learner.online_batches_per_update
    return online_batch(run.offline_buffer, k, torch.device("cpu"))


def _modules_state(run: O2ORun) -> dict:
    return copy.deepcopy({name: m.state_dict() for name, m in run.learner.modules().items()})


def _load(run: O2ORun, state: dict) -> None:
    for name, module in run.learner.modules().items():
        module.load_state_dict(copy.deepcopy(state[name]))


def contract_failures(run: O2ORun) -> list[str]:
    """The checks of the module docstring that ``run``'s update fails, offline and online."""
    failures = []
    for online in (False, True):
        phase = "online" if online else "offline"
        if online:
            run.frames = 100
            run.learner.collector_started()
        run.learner.update(_batch(run, online))  # first call: optimizer state, phases
        traces, states = [], []
        for _ in range(UPDATES):
            batch = _batch(run, online)
            before = python_state(run.learner)
            with OpTrace() as trace:
                run.learner.update(batch)
            traces.append(trace.ops)
            states.append((before, python_state(run.learner)))
        if any(ops != traces[0] for ops in traces[1:]):
            failures.append(f"{phase}: the kernels differ from one update to the next")
        changed = sorted(
            {k for a, b in states for k in a.keys() | b.keys() if not _same(a.get(k), b.get(k))}
        )
        if changed:
            failures.append(f"{phase}: the update changes Python state {changed[:4]}")
        batch = _batch(run, online)
        other = batch.clone()
        other["next", "reward"] += 1.0
        other["observation"] += 0.5
        state, rng = _modules_state(run), torch.get_rng_state()
        first = run.learner.update(batch)
        _load(run, state)
        torch.set_rng_state(rng)
        second = run.learner.update(other)
        if all(torch.equal(first[k], second[k]) for k in first):
            failures.append(f"{phase}: the update does not read its batch")
    return failures


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("graph_safe_data")


@pytest.mark.long_running(seconds=30)
@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_an_update_is_graph_safe_exactly_when_its_table_entry_says_so(algo, tmp_path, cache):
    failures = contract_failures(_run(algo, tmp_path, cache))
    reason = ALGORITHMS[algo].no_cuda_graph
    if reason is None:
        assert not failures, failures
    else:
        assert failures, f"{algo} passes every check, yet its entry says: {reason}"


def test_cudagraphs_is_refused_off_cuda_and_for_an_algorithm_that_cannot(tmp_path):
    base = [*TINY, f"output_dir={tmp_path}", "compile.cudagraphs=true"]
    with pytest.raises(ConfigError, match=r"^compile.cudagraphs=true: not for algo=dacer: its"):
        compose_checked(CONFIG_DIR, [*base, "algo=dacer"])
    if not torch.cuda.is_available():
        with pytest.raises(
            ConfigError,
            match=r"^compile.cudagraphs=true: CUDA graphs replay CUDA kernels: needs "
            r"device=cuda \(device=cpu\); compile.compile=true works on any device$",
        ):
            compose_checked(CONFIG_DIR, base)


class _StandInGraph:
    """Records what ``GraphedUpdate`` builds; runs its module eagerly (the real
    ``CudaGraphModule`` needs CUDA and, once built, changes tensordict's pytree registry
    for the whole process)."""

    built: list[dict] = []

    def __init__(self, module, **kwargs) -> None:
        self.module = module
        _StandInGraph.built.append(kwargs)

    def __call__(self, td):
        return self.module(td)


def test_one_graph_per_phase_and_batch_shape_and_the_optimizers_made_capturable_first(
    monkeypatch,
):
    import tensordict.nn
    from tensordict import TensorDict

    from torchrl_dual.recipe.settings.schema import CompileSettings

    monkeypatch.setattr(tensordict.nn, "CudaGraphModule", _StandInGraph)
    w = torch.nn.Parameter(torch.ones(3))
    adam = torch.optim.Adam([w])
    w.sum().backward()
    adam.step()  # a state, as after a resume (a capturable Adam cannot step on a CPU)
    calls, phase = [], {"online": False}

    class Learner:
        def __init__(self) -> None:
            self.optimizers = [adam]

        def update(self, batch):
            calls.append((tuple(batch.shape), adam.param_groups[0]["capturable"]))
            return {"loss": (w * batch["x"]).sum().detach()}

    settings = CompileSettings(compile=False, compile_mode=None, cudagraphs=True)
    step = make_update_step(Learner(), settings, lambda: phase["online"])
    assert isinstance(step, GraphedUpdate)
    out = step(TensorDict(x=torch.ones(2, 3), batch_size=[2]))
    assert set(out) == {"loss"} and isinstance(out, dict)
    step(TensorDict(x=torch.ones(2, 3), batch_size=[2]))
    phase["online"] = True
    step(TensorDict(x=torch.ones(4, 2, 3), batch_size=[4, 2]))
    assert set(step.graphs) == {(False, (2,)), (True, (4, 2))}
    assert calls == [((2,), True), ((2,), True), ((4, 2), True)]
    assert (
        _StandInGraph.built[-2:]
        == [{"in_keys": [], "out_keys": [], "warmup": CUDA_GRAPH_WARMUP}] * 2
    )
    assert adam.state[w]["step"].dtype == torch.float32


def test_a_replayed_update_moves_the_version_counters_of_the_optimizers_parameters(
    monkeypatch,
):
    """A CUDA graph's replay changes the weights without moving their version counters;
    the acting path's caches read those counters, so the step moves them by hand."""
    import tensordict.nn
    from tensordict import TensorDict

    from torchrl_dual.recipe.settings.schema import CompileSettings

    class _Replay(_StandInGraph):
        def __call__(self, td):  # the weights change, no counter moves (as a replay)
            with torch.no_grad():
                w.data.add_(1.0)
            return TensorDict(loss=w.detach().sum())

    monkeypatch.setattr(tensordict.nn, "CudaGraphModule", _Replay)
    w = torch.nn.Parameter(torch.ones(3))

    class Learner:
        def __init__(self) -> None:
            self.optimizer = torch.optim.SGD([w], lr=0.1)

        def update(self, batch):
            return {"loss": w.sum().detach()}

    settings = CompileSettings(compile=False, compile_mode=None, cudagraphs=True)
    step = make_update_step(Learner(), settings, lambda: "offline")
    versions = [w._version]
    for _ in range(2):
        step(TensorDict(x=torch.ones(2, 3), batch_size=[2]))
        versions.append(w._version)
    assert versions[0] < versions[1] < versions[2]
