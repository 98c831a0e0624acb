"""``collector=ray`` (``torchrl_dual/recipe/o2o/ray_collector.py``): TorchRL's RayCollector.

One DUAL run with two remote collectors (Ray actors) on a local Ray runtime of 2 CPUs that
the run starts itself: it stores one transition per collected frame, in episodes that are
each one contiguous trajectory of one actor under an id of their own (the actors' own
trajectory ids would collide: each remote collector numbers its trajectories from 0), each
actor's ``previous_*`` keys follow its own trajectory, every actor holds the learner's
parameters *and buffers* (DUAL's Laplace posterior draws, which change at each refit) after
every push, and the run ends the Ray runtime it started. Plus the config errors of
``collector=ray``.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict
from test_collectors import (
    CONFIG_DIR,
    assert_contiguous_episodes,
    assert_previous_keys_follow_trajectories,
    time_limit,
    two_worker_run,
)

from torchrl_dual.recipe import O2ORun, RecipeSettings, compose_checked, run
from torchrl_dual.recipe.o2o.ray_collector import InterleavedTrajectories
from torchrl_dual.recipe.settings import o2o as o2o_settings
from torchrl_dual.recipe.settings.errors import ConfigError, UserError
from torchrl_dual.recipe.settings.o2o import COLLECTORS

pytestmark = [
    pytest.mark.usefixtures("ray_exclusive"),
    pytest.mark.long_running(seconds=45),
]  # starts first under xdist; one Ray module at a time
needs_ray = pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="ray is not installed (pip install 'torchrl-dual[ray]')",
)


def ray_children() -> list[str]:
    """Names of this process's child processes that belong to Ray (GCS, raylet, ...)."""
    names = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            pid_name, rest = stat.read_text().rsplit(")", 1)
        except OSError:  # the process ended meanwhile
            continue
        if int(rest.split()[1]) == os.getpid() and "ray" in pid_name.lower():
            names.append(pid_name.split("(", 1)[1])
    return names


@pytest.fixture(scope="module")
def ray_run(tmp_path_factory):
    """DUAL with ``collector=ray collector.num_workers=2`` (asynchronous); records every
    batch ``store`` receives and, after every push, the learner's weights and each actor's."""
    import ray

    # collector.address=local: a new local runtime, even if this machine runs a cluster
    overrides = two_worker_run(tmp_path_factory, "ray", "collector.address=local")
    batches, pushes, during = [], [], []
    kind, store = COLLECTORS["ray"], O2ORun.store

    def recording_store(self, batch):
        batches.append(batch.clone())
        during.append(ray.is_initialized())
        return store(self, batch)

    def recording_push(collector, policy):
        kind.push(collector, policy)
        actors = collector.get_distant_attr("policy")  # each actor's policy, pickled back
        learner = TensorDict.from_module(policy).data.clone()
        pushes.append((learner, [TensorDict.from_module(actor).data for actor in actors]))

    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("RAY_OVERRIDE_RESOURCES", '{"CPU": 2}')  # the runtime: 2 CPUs
        patch.setitem(COLLECTORS, "ray", kind._replace(push=recording_push))
        patch.setattr(O2ORun, "store", recording_store)
        with time_limit(300):
            final = run(compose_checked(CONFIG_DIR, overrides))
    buffers = {name for name, _ in final.learner.exploration_policy.named_buffers()}
    return SimpleNamespace(
        final=final.state(),
        batches=batches,
        pushes=pushes,
        buffers={tuple(name.split(".")) for name in buffers},
        offline_max=int(final.data.transitions["episode"].max()),
        ray_during=during,
        ray_after=ray.is_initialized(),
        children_after=ray_children(),
    )


@needs_ray
def test_a_ray_run_stores_every_frame_once_in_unique_contiguous_episodes(ray_run):
    online = ray_run.final["online_data"]
    assert ray_run.final["frames"] == 120
    assert len(online) == 120 == sum(b.numel() for b in ray_run.batches)
    assert online["episode"].min() > ray_run.offline_max
    assert_contiguous_episodes(online)
    # both actors' batches were stored, their trajectory ids interleaved (0, 2, ... and
    # 1, 3, ...): without the offset both would start at 0 and two actors' steps would be
    # stored as one episode, which assert_contiguous_episodes would catch
    parities = {int(b["collector", "traj_ids"][0]) % 2 for b in ray_run.batches}
    assert parities == {0, 1}
    for batch in ray_run.batches:
        assert len(set((batch["collector", "traj_ids"] % 2).tolist())) == 1  # one actor


@needs_ray
def test_each_actor_s_previous_keys_follow_its_own_trajectory(ray_run):
    assert assert_previous_keys_follow_trajectories(ray_run.batches) > 60


@needs_ray
def test_every_actor_acts_with_the_pushed_parameters_and_buffers(ray_run):
    assert len(ray_run.pushes) == 6  # one per update block (120 frames / 20)
    for learner, actors in ray_run.pushes:
        assert len(actors) == 2
        for actor in actors:
            assert set(actor.keys(True, True)) == set(learner.keys(True, True))
            assert (actor == learner).all()
    # the Laplace draws (buffers) and the parameters changed between the first and the
    # last push, so the equality above is not the one of unchanged weights
    first, last = ray_run.pushes[0][0], ray_run.pushes[-1][0]
    changed = {key for key in last.keys(True, True) if not torch.equal(first[key], last[key])}
    assert changed & ray_run.buffers
    assert changed - ray_run.buffers


@needs_ray
def test_the_run_ends_the_ray_runtime_it_started(ray_run):
    assert all(ray_run.ray_during)
    assert not ray_run.ray_after
    assert ray_run.children_after == []


def test_interleaved_trajectory_ids_are_unique_across_collectors():
    pools = [InterleavedTrajectories(worker, 3) for worker in range(3)]
    ids = [pool.get_traj_and_increment(n) for pool, n in zip(pools, (4, 1, 2), strict=True)]
    ids += [pools[1].get_traj_and_increment(torch.tensor(3))]  # TorchRL passes a tensor
    flat = torch.cat(ids).tolist()
    assert len(flat) == len(set(flat)) == 10
    assert sorted(i for i in flat if i % 3 == 1) == [1, 4, 7, 10]


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (
            ["collector.num_workers=3", "collector.sync=true", "budget.frames_per_batch=20"],
            "budget.frames_per_batch=20: collector=ray collector.sync=true splits each batch "
            "over collector.num_workers=3: use a multiple of it",
        ),
        (["device=cuda"], "device=cuda: collector=ray's remote collectors act on the CPUs"),
        (
            ["algo=calql"],
            "collector=ray: critic=calql labels one stream of online episodes with "
            "Monte-Carlo returns; use collector=single with it",
        ),
        (["collector.sync=maybe"], "collector.sync=maybe: must be true or false"),
        (["collector.address=''"], "collector.address=: must be null or a non-empty string"),
    ],
)
def test_collector_ray_config_errors(overrides, message, tmp_path, monkeypatch):
    monkeypatch.setattr(o2o_settings, "ray_installed", lambda: True)
    base = ["collector=ray", f"output_dir={tmp_path / 'run'}", "data_cache_dir=null"]
    with pytest.raises(ConfigError) as error:
        compose_checked(CONFIG_DIR, [*base, *overrides])
    assert str(error.value).startswith(message)


def test_collector_ray_without_ray_names_the_extra_to_install(tmp_path, monkeypatch):
    monkeypatch.setattr(o2o_settings, "ray_installed", lambda: False)
    with pytest.raises(ConfigError) as error:
        compose_checked(CONFIG_DIR, ["collector=ray", f"output_dir={tmp_path / 'run'}"])
    assert str(error.value) == (
        'collector=ray: needs Ray, which is not installed: pip install "torchrl-dual[ray]"'
    )


@needs_ray
def test_collector_address_auto_without_a_cluster_is_a_user_error(tmp_path, monkeypatch):
    import ray
    from ray._private.services import canonicalize_bootstrap_address

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    if ray.is_initialized() or canonicalize_bootstrap_address(None) is not None:
        pytest.skip("a Ray runtime or cluster runs here: auto would connect to it")
    cfg = compose_checked(
        CONFIG_DIR, ["collector=ray", "collector.address=auto", f"output_dir={tmp_path}"]
    )
    fake_run = SimpleNamespace(
        settings=RecipeSettings.of(cfg),
        data=None,
        frames=0,
        learner=SimpleNamespace(exploration_policy=torch.nn.Linear(1, 1)),
    )
    with pytest.raises(UserError) as error:
        COLLECTORS["ray"].make(fake_run, 100)
    assert str(error.value).startswith("collector.address=auto: Could not find any running")
    assert str(error.value).endswith(
        "Start a cluster (ray start --head) or use collector.address=null for a local Ray runtime"
    )
    assert not ray.is_initialized()
