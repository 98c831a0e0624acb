"""``collector=single|multi_sync|multi_async`` (``torchrl_dual/recipe/o2o/collectors.py``).

A DUAL run with two ``multi_sync`` workers, interrupted and resumed with two
``multi_async`` ones in this process,
stores one transition per collected frame, each episode one contiguous trajectory under an
id never used before (also across the resume), and each worker's ``previous_*`` keys
follow that worker's own trajectory. Workers act with the latest weights: a buffer
*replaced* (not updated in place, so shared memory alone cannot carry it) reaches the
workers' next batch after the push (``push_to_processes``), and not before. Episode ids of one worker
are those of the former single-stream formula. No worker process outlives a run, and the
run shuts its collector down on Ctrl-C and on an error.
"""

from __future__ import annotations

import multiprocessing
import signal
from contextlib import contextmanager
from types import SimpleNamespace

import pytest
import torch
from tensordict.nn import TensorDictModule
from torch import nn

from torchrl_dual.recipe import CONFIG_DIR, O2ORun, RecipeSettings, compose_checked, run
from torchrl_dual.recipe.o2o.episodes import assign_episodes
from torchrl_dual.recipe.settings.o2o import COLLECTORS

pytestmark = pytest.mark.long_running(seconds=55)  # starts first under xdist
# DUAL at the smoke budget cut down: 120 online frames in batches of 20 (episodes of 15
# steps, so some end inside a batch and some span two), interrupted after 60
FAST = [
    "budget=smoke",
    "budget.planner_updates=10",
    "budget.distill_updates=[2,2,2,2,2]",
    "budget.offline_updates=10",
    "online.utd_ratio=0.1",
    "budget.online_frames=120",
    "budget.frames_per_batch=20",
    "budget.eval_every=120",
    "budget.checkpoint_every=120",
    "budget.eval_episodes=1",
    "budget.laplace_refit_every=2",
    "env.max_episode_steps=15",
    "progress=false",
    "num_threads=1",
]


@contextmanager
def time_limit(seconds: int):
    """Fails what would hang (a worker that never answers) after ``seconds``; the run's
    ``finally`` then shuts its workers down."""

    def expire(*_):
        raise TimeoutError(f"collection took more than {seconds} s")

    previous = signal.signal(signal.SIGALRM, expire)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def two_worker_run(tmp_path_factory, collector, *extra):
    """The overrides of a FAST run with ``collector`` and 2 workers, in fresh directories."""
    out = tmp_path_factory.mktemp(collector) / "run"
    cache = tmp_path_factory.mktemp(f"{collector}_data")
    options = [f"collector={collector}", "collector.num_workers=2", *extra]
    return [*FAST, f"output_dir={out}", f"data_cache_dir={cache}", *options]


@pytest.fixture(scope="module")
def async_run(tmp_path_factory):
    """DUAL with ``collector=multi_sync`` (2 workers), interrupted at 60 frames, resumed
    with ``collector=multi_async`` (the collector may change on resume, as on a machine
    with other cores); every collected batch is recorded as ``store`` receives it."""
    overrides = two_worker_run(tmp_path_factory, "multi_async")
    first_half = [o.replace("collector=multi_async", "collector=multi_sync") for o in overrides]
    batches: list = []
    original = O2ORun.store

    def store(self, batch):
        batches.append(batch.clone())
        return original(self, batch)

    O2ORun.store = store
    try:
        with time_limit(300):
            first = run(compose_checked(CONFIG_DIR, [*first_half, "interrupt_at_frames=60"]))
            interrupted = first.state()
            children_between = multiprocessing.active_children()
            second = run(compose_checked(CONFIG_DIR, [*overrides, "resume=true"]))
    finally:
        O2ORun.store = original
    return SimpleNamespace(
        interrupted=interrupted,
        final=second.state(),
        batches=batches,
        offline_max=int(second.data.transitions["episode"].max()),
        children_between=children_between,
        children_after=multiprocessing.active_children(),
    )


def episodes_of(online):
    """``episode id -> its transitions`` in storage order."""
    ids = online["episode"].reshape(-1)
    return {int(e): online[ids == e] for e in ids.unique()}


def assert_contiguous_episodes(online, max_steps=15):
    """Each stored episode is one trajectory: each transition starts where the previous one
    ended, at most ``max_steps`` (env.max_episode_steps) long, done at most at its end."""
    for episode in episodes_of(online).values():
        assert torch.equal(episode["observation"][1:], episode["next", "observation"][:-1])
        assert len(episode) <= max_steps
        assert not episode["next", "done"][:-1].any()


def assert_previous_keys_follow_trajectories(batches):
    """In every collected batch, each trajectory's ``previous_*`` keys are its own previous
    step (none at its first step); returns how many steps were checked."""
    checked = 0
    for batch in (b.reshape(-1) for b in batches):  # multi_sync: [workers, frames]
        for traj in batch["collector", "traj_ids"].unique():
            steps = batch[batch["collector", "traj_ids"] == traj]
            valid = steps["previous_valid"].reshape(-1)
            # a trajectory's first step has no previous step; later ones have theirs
            assert torch.equal(steps["previous_observation"][1:], steps["observation"][:-1])
            assert torch.equal(steps["previous_action"][1:], steps["action"][:-1])
            assert valid[1:].all()
            checked += len(steps) - 1
        first = batch["previous_valid"].reshape(-1) == 0
        assert (batch["previous_observation"][first] == 0).all()
    return checked


def test_a_multi_worker_run_stores_every_frame_once_with_unique_contiguous_episodes(async_run):
    interrupted, final = async_run.interrupted, async_run.final
    assert (interrupted["frames"], final["frames"]) == (60, 120)
    online = final["online_data"]
    assert len(online) == 120 == sum(b.numel() for b in async_run.batches)
    assert len(interrupted["online_data"]) == 60
    # ids: above the offline ones; the resumed collector's episodes never reuse an old id
    before = set(interrupted["online_data"]["episode"].tolist())
    after = set(online[60:]["episode"].tolist())
    assert min(before | after) > async_run.offline_max
    assert before.isdisjoint(after)
    assert_contiguous_episodes(online)
    # both workers' batches were stored (async: whichever is ready first)
    assert len({b["collector", "traj_ids"].min().item() for b in async_run.batches}) > 1
    # multi_sync's [workers, frames] batches before the resume, multi_async's after
    assert [tuple(b.shape) for b in async_run.batches] == [(2, 10)] * 3 + [(20,)] * 3


def test_each_worker_s_previous_keys_follow_its_own_trajectory(async_run):
    assert assert_previous_keys_follow_trajectories(async_run.batches) > 60


def test_no_worker_outlives_an_interrupted_or_finished_run(async_run):
    assert async_run.children_between == [] and async_run.children_after == []


class ConstantAction(nn.Module):
    """``action = a + b``: a parameter and a buffer (as DUAL's Laplace draws are)."""

    def __init__(self) -> None:
        super().__init__()
        self.a = nn.Parameter(torch.zeros(2))
        self.register_buffer("b", torch.zeros(2))

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        return (self.a + self.b).expand(*observation.shape[:-1], 2)


def test_workers_act_with_the_weights_and_buffers_pushed_after_an_update_block():
    cfg = compose_checked(CONFIG_DIR, [*FAST, "collector=multi_sync", "collector.num_workers=2"])
    module = ConstantAction()
    policy = TensorDictModule(module, in_keys=["observation"], out_keys=["action"])
    fake_run = SimpleNamespace(
        settings=RecipeSettings.of(cfg),
        data=None,
        frames=0,
        learner=SimpleNamespace(exploration_policy=policy),
    )
    kind = COLLECTORS["multi_sync"]
    collector = kind.make(fake_run, 200)
    seen = []
    try:
        with time_limit(120):
            for i, batch in enumerate(collector):
                assert batch.shape == (2, 10)  # [workers, frames_per_batch / workers]
                seen.append(batch["action"][..., 0].unique().tolist())
                if i == 0:  # an update block: a parameter changed, a buffer replaced
                    with torch.no_grad():
                        module.a.add_(0.5)
                    module.b = torch.full((2,), 0.25)
                    kind.push(collector, policy)
                if i == 1:  # changed again, not pushed: the workers keep the last push
                    with torch.no_grad():
                        module.a.add_(10.0)
                    module.b.fill_(-1.0)
                if i == 2:
                    kind.push(collector, policy)
                if i == 3:
                    break
    finally:
        collector.shutdown()
    assert seen == [[0.0], [0.75], [0.75], [9.5]]
    assert multiprocessing.active_children() == []


def test_one_worker_s_episode_ids_are_the_single_stream_cumsum():
    generator = torch.Generator().manual_seed(0)
    done = torch.rand(200, generator=generator) < 0.1
    traj = torch.cumsum(done.long(), 0) - done.long()  # what a collector writes
    expected = 7 + traj  # the former store(): next_episode + cumsum(done) - done
    open_episodes, next_episode, ids = {}, 7, []
    for start in range(0, 200, 30):  # batches of 30 frames
        chunk, next_episode = assign_episodes(
            traj[start : start + 30], done[start : start + 30], open_episodes, next_episode
        )
        ids.append(chunk)
    assert torch.equal(torch.cat(ids), expected)
    assert next_episode == int(expected[-1]) + 1
    assert open_episodes == ({} if done[-1] else {int(traj[-1]): int(expected[-1])})


class FailingCollector:
    """Yields nothing but ``error``; records whether the run shut it down."""

    def __init__(self, error: BaseException) -> None:
        self.error, self.shut_down = error, False

    def __iter__(self):
        raise self.error
        yield  # a generator

    def shutdown(self) -> None:
        self.shut_down = True


@pytest.mark.parametrize("error", [KeyboardInterrupt(), RuntimeError("worker 1 died")])
def test_the_collector_is_shut_down_on_ctrl_c_and_on_an_error(error, tmp_path, monkeypatch):
    collector = FailingCollector(error)
    monkeypatch.setattr(O2ORun, "collector", lambda self: collector)
    overrides = [
        "algo=iql",
        "budget=smoke",
        "budget.offline_updates=0",
        "budget.eval_episodes=1",
        "env.max_episode_steps=15",
        "progress=false",
        f"output_dir={tmp_path / 'run'}",
        f"data_cache_dir={tmp_path / 'data'}",
    ]
    cfg = compose_checked(CONFIG_DIR, overrides)
    if isinstance(error, KeyboardInterrupt):  # Ctrl-C: checkpoint, then the workers end
        assert run(cfg).frames == 0
    else:
        with pytest.raises(RuntimeError, match="worker 1 died"):
            run(cfg)
    assert collector.shut_down
