"""One update and one acting step of every algorithm read nothing back to the host, and
every acting policy compiles whole (issue 30 items 1-2).

Each ``ALGORITHMS`` entry's learner, on Frozen-Lake at tiny sizes, runs one update under a
``TorchDispatchMode`` that counts ``aten._local_scalar_dense`` (``.item()``, ``float(t)``,
``bool(t)``) and ``nonzero``: on a GPU each is a device-to-host sync. The NaN input checks
are switched off as under ``torch.compile`` (``host_reads_allowed``); the optimizers' own
reads of their CPU ``step`` counters (``capturable=False``: host tensors on a GPU too) are
not syncs and are not counted. The metrics an update returns stay on the device.
"""

from __future__ import annotations

import collections
import traceback
from pathlib import Path

import pytest
import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torchrl.envs.utils import ExplorationType, set_exploration_type

import torchrl_dual._utils as utils
from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, O2ORun, compose_checked
from torchrl_dual.recipe.o2o.loop import online_batch
from torchrl_dual.recipe.o2o.update_step import optimizers_of

TINY = (
    "budget=smoke", "env=frozenlake", "budget.dataset_transitions=1000",
    "budget.network_width=16", "budget.batch_size=32", "progress=false", "num_threads=1",
)  # fmt: skip
TORCHRL_READS = {
    # TanhNormal's ``high > low`` check: TorchRL skips it while compiling or capturing
    "torchrl/modules/distributions/continuous.py:427",
    "torchrl/modules/distributions/continuous.py:471",
    # SliceSampler's trajectory lengths: the replay's sampling (Diffuser samples windows
    # inside its update), not the update
    "torchrl/data/replay_buffers/samplers/slice.py:1035",
    "torchrl/data/replay_buffers/samplers/slice.py:1038",
    # a safe actor's spec.project (its is_in check): TorchRL skips it while compiling
    "torchrl/data/tensor_specs.py:2648",
    "torchrl/data/tensor_specs.py:1100",
}
"""The host reads that TorchRL's code makes, by the frame that makes them."""
ONLINE_EXTRA = {"dacer": ("dacer.entropy_every=1",)}  # its regulator in every update
HOST_READS = {torch.ops.aten._local_scalar_dense.default, torch.ops.aten.nonzero.default}


class HostReads(TorchDispatchMode):
    """Counts host reads of tensors other than ``ignored`` (by identity)."""

    def __init__(self, ignored: set[int]) -> None:
        super().__init__()
        self.ignored = ignored
        self.count: collections.Counter = collections.Counter()

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func in HOST_READS and id(args[0]) not in self.ignored:
            self.count[_where()] += 1
        return func(*args, **(kwargs or {}))


def _where() -> str:
    """The innermost frame of this package or of TorchRL: what to fix."""
    frames = [
        f"{f.filename.rsplit('site-packages/', 1)[-1]}:{f.lineno}"
        for f in traceback.extract_stack()
        if "torchrl_dual/" in f.filename or "/torchrl/" in f.filename
    ]
    return frames[-1] if frames else "?"


def optimizer_steps(learner) -> set[int]:
    """``id`` of every optimizer ``step`` counter of the learner (Adam keeps it on the CPU
    unless capturable: its reads are not the update's)."""
    return {id(s["step"]) for o in optimizers_of(learner) for s in o.state.values() if "step" in s}


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("host_reads_data")


@pytest.mark.parametrize("online", [False, True], ids=["offline", "online"])
@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_one_update_reads_nothing_back_to_the_host(algo, online, cache_dir, tmp_path, monkeypatch):
    """Offline and online (the online critic settings, SO2's stacked batches, DACER's
    entropy regulator at every update)."""
    cfg = compose_checked(
        CONFIG_DIR,
        [*TINY, *ONLINE_EXTRA.get(algo, ()), f"algo={algo}", f"output_dir={tmp_path}",
         f"data_cache_dir={cache_dir}"],
    )  # fmt: skip
    run = O2ORun(cfg, ALGORITHMS[algo].learner)
    if online:
        run.frames = 100
        run.learner.collector_started()
    k = run.learner.online_batches_per_update if online else 1
    run.learner.update(online_batch(run.offline_buffer, k, torch.device("cpu")))  # state
    batch = online_batch(run.offline_buffer, k, torch.device("cpu"))
    monkeypatch.setattr(utils, "host_reads_allowed", lambda: False)
    with HostReads(optimizer_steps(run.learner)) as reads:
        metrics = run.learner.update(batch)
    ours = {where: n for where, n in reads.count.items() if "torchrl_dual/" in where}
    assert not ours, ours  # TorchRL's own (TanhNormal's box check, skipped under compile)
    assert set(reads.count) - set(ours) <= TORCHRL_READS, reads.count
    assert all(isinstance(v, torch.Tensor) for v in metrics.values()), metrics


@pytest.mark.long_running(seconds=40)
@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_the_acting_policy_reads_nothing_back_and_compiles_whole(
    algo, cache_dir, tmp_path, monkeypatch
):
    """After the offline phase, one acting step (RANDOM, as the collector acts) reads nothing
    back to the host once the eager input checks are off, and the policy compiles with
    ``fullgraph=True`` to the eager actions (DETERMINISTIC, as the evaluation acts)."""
    cfg = compose_checked(
        CONFIG_DIR,
        [*TINY, f"algo={algo}", f"output_dir={tmp_path}", f"data_cache_dir={cache_dir}"],
    )
    run = O2ORun(cfg, ALGORITHMS[algo].learner)
    for name, stage in run.learner.offline_stages():
        run.stage(name, stage)
    policy, state = run.learner.exploration_policy, run.env.reset()
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        policy(state.clone())  # first call: caches and memos
        monkeypatch.setattr(utils, "host_reads_allowed", lambda: False)
        with HostReads(set()) as reads:
            policy(state.clone())
    ours = {where: n for where, n in reads.count.items() if "torchrl_dual/" in where}
    assert not ours, ours
    assert set(reads.count) - set(ours) <= TORCHRL_READS, reads.count
    monkeypatch.undo()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        eager = policy(state.clone())
        torch._dynamo.reset()
        compiled = torch.compile(policy, fullgraph=True, backend="eager")(state.clone())
    torch.testing.assert_close(compiled["action"], eager["action"])
