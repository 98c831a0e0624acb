"""``offline_cache=``: runs that differ only in online keys share one offline phase.

The promise under test: a run that loads the shared offline phase continues exactly as
if it had computed it itself (same scores, same metric files), and a change to any key
an offline stage reads is a different entry.
"""

from __future__ import annotations

import json
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from omegaconf import OmegaConf
from recipe_runner import failed, run_recipe, succeeded

from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR
from torchrl_dual.recipe import compose_checked
from torchrl_dual.recipe.algos.dual import DualLearner
from torchrl_dual.recipe.o2o import offline_cache
from torchrl_dual.recipe.o2o.offline_cache import OfflinePhaseCache, offline_key_config

pytestmark = pytest.mark.long_running(seconds=40)  # starts first under xdist
# DUAL's online ablations on a shifted env: everything the online phase reads differs
FOLLOWER = ("env.shift=rotation", "laplace.num_samples=0", "exploration.shift_weight=0")
# the smoke budget cut down (what is under test is the sharing, not the training)
FAST = (
    "budget.planner_updates=10",
    "budget.distill_updates=[2,2,2,2,2]",
    "budget.offline_updates=10",
    "budget.online_frames=200",
    "budget.eval_every=200",
    "budget.eval_episodes=1",
)


def summary(output_dir: Path) -> dict:
    return json.loads((output_dir / "summary.json").read_text())


def scalars(output_dir: Path, prefix: str) -> dict[str, str]:
    """CSV metric files under ``logs/dual/scalars/<prefix>`` by name -> content."""
    root = output_dir / "logs" / "dual" / "scalars"
    return {p.name: p.read_text() for p in sorted((root / prefix).glob("*.csv"))}


@pytest.fixture(scope="module")
def shared_runs(tmp_path_factory) -> dict:
    """A leader that computes the offline phase, a follower that loads it, and the
    follower's settings run without the cache as the reference."""
    root = tmp_path_factory.mktemp("offline_cache")
    data, cache = root / "data", root / "cache"
    runs = {
        "leader": (root / "leader", (f"offline_cache={cache}",)),
        "follower": (root / "follower", (f"offline_cache={cache}", *FOLLOWER)),
        "reference": (root / "reference", FOLLOWER),
    }
    procs = {
        name: succeeded(run_recipe(out, data, *FAST, *args)) for name, (out, args) in runs.items()
    }
    return {"root": root, "cache": cache, "data": data, "procs": procs} | {
        name: out for name, (out, _) in runs.items()
    }


def test_a_follower_loads_the_shared_offline_phase(shared_runs):
    assert "loaded from" not in shared_runs["procs"]["leader"].stdout
    assert "offline stages planner, distillation, actor_critic: loaded from" in (
        shared_runs["procs"]["follower"].stdout
    )
    assert not summary(shared_runs["leader"])["shared_offline"]
    assert summary(shared_runs["follower"])["shared_offline"]


def test_a_shifted_run_prints_its_score_without_the_shift_too(shared_runs):
    history = summary(shared_runs["follower"])["history"]
    plain = history[-1]["normalized_score_unshifted"]
    assert f"; without the shift {plain:.1f}" in shared_runs["procs"]["follower"].stdout
    assert "without the shift" not in shared_runs["procs"]["leader"].stdout  # no shift
    assert len(list(shared_runs["cache"].iterdir())) == 1  # one entry for both


def test_loading_the_offline_phase_changes_nothing_the_run_computes(shared_runs):
    follower, reference = summary(shared_runs["follower"]), summary(shared_runs["reference"])
    assert follower["history"] == reference["history"]
    for prefix in ("planner", "offline", "online", "eval"):
        got = scalars(shared_runs["follower"], prefix)
        assert got, prefix
        assert got == scalars(shared_runs["reference"], prefix), prefix


def test_the_summary_charges_the_shared_stages_at_their_first_cost(shared_runs):
    leader, follower = summary(shared_runs["leader"]), summary(shared_runs["follower"])
    for stage in DualLearner.shared_stages:
        assert follower["stage_seconds"][stage] == leader["stage_seconds"][stage]
        assert follower["stage_cpu_seconds"][stage] == leader["stage_cpu_seconds"][stage]
    assert set(follower["stage_cpu_seconds"]) == set(follower["stage_seconds"])
    assert follower["cpu_seconds"] == pytest.approx(
        sum(follower["stage_cpu_seconds"].values()), abs=1e-2
    )
    # stages that compute something took CPU time (the follower's Laplace stage, with
    # laplace.num_samples=0, has nothing to fit and may round to 0)
    cpu = follower["stage_cpu_seconds"]
    assert all(cpu[stage] > 0 for stage in (*DualLearner.shared_stages, "online"))
    stages = follower["stage_seconds"]
    assert follower["offline_seconds"] == pytest.approx(
        sum(v for k, v in stages.items() if k != "online"), abs=1e-2
    )
    assert follower["wall_seconds"] == pytest.approx(
        follower["offline_seconds"] + stages["online"], abs=1e-2
    )
    assert follower["shift"] == "rotation" and follower["frames"] == 200


def test_a_corrupt_snapshot_is_named_with_the_fix(shared_runs, tmp_path):
    (entry,) = list(shared_runs["cache"].iterdir())
    cache = tmp_path / "cache"
    target = cache / entry.name
    target.mkdir(parents=True)
    (target / "offline_phase.pt").write_bytes(b"not a checkpoint")
    run = run_recipe(tmp_path / "run", shared_runs["data"], *FAST, f"offline_cache={cache}")
    line = failed(run)
    assert line.startswith(f"error: offline_cache={cache}:")
    assert "delete that directory to recompute it" in line


def key(*overrides: str) -> str:
    # a fresh output_dir (not part of the key): the default one may hold a user's run
    fresh = f"output_dir={tempfile.mkdtemp()}"
    cfg = compose_checked(RECIPE_CONFIG_DIR, ["budget=smoke", fresh, *overrides])
    config = offline_key_config(OmegaConf.to_container(cfg, resolve=True), DualLearner.online_keys)
    return OfflinePhaseCache("/unused", config, "x").key


def test_online_keys_share_the_key_and_offline_keys_do_not():
    base = key()
    for online in (
        *FOLLOWER,
        "online.utd_ratio=1.0",
        "budget.online_frames=100",
        "collector=multi_async",
        "progress=false",  # display and error display: a run with a progress bar or
        "debug=true",  # tracebacks shares with the suite's, which has neither
        "data_cache_dir=/elsewhere",
    ):
        assert key(online) == base, online
    for offline in ("planner.lr=0.001", "seed=1", "budget.offline_updates=7", "actor.init=scratch"):
        assert key(offline) != base, offline


def test_a_new_offline_phase_revision_is_a_new_entry(monkeypatch):
    """A code change that alters the offline stages (a bumped revision) must not reuse the
    snapshots written before it."""
    base = key()
    monkeypatch.setattr(
        offline_cache, "OFFLINE_PHASE_REVISION", offline_cache.OFFLINE_PHASE_REVISION + 1
    )
    assert key() != base


def test_the_lock_makes_a_second_run_wait_for_the_first(tmp_path):
    cache = OfflinePhaseCache(tmp_path, {"seed": 0}, "x")
    order: list[str] = []
    first_has_lock, release = threading.Event(), threading.Event()

    def first() -> None:
        with cache.lock():
            order.append("first in")
            first_has_lock.set()
            release.wait(10)
            cache.save({"w": 1}, logs_dir=None)
            order.append("first out")

    def second() -> None:
        first_has_lock.wait(10)
        with cache.lock():
            order.append(f"second in, snapshot {'found' if cache.exists() else 'missing'}")

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for thread in threads:
        thread.start()
    first_has_lock.wait(10)
    release.set()
    for thread in threads:
        thread.join(20)
    assert order == ["first in", "first out", "second in, snapshot found"]


def test_an_augmenting_follower_loads_the_offline_phase_of_a_plain_one(shared_runs, tmp_path):
    """``augment.kind=planner`` is online-only: its run loads the offline phase of a run
    without the augmenter (whose learner state has no augmenter counters) and augments."""
    out = tmp_path / "augment"
    augment = ("augment.kind=planner", "augment.every=20", "augment.num_windows=4")
    budget = ("augment.guider_updates=2", "augment.reward_updates=2")
    proc = succeeded(
        run_recipe(
            out, shared_runs["data"], *FAST, f"offline_cache={shared_runs['cache']}",
            *augment, *budget,
        )
    )  # fmt: skip
    assert "offline stages planner, distillation, actor_critic: loaded from" in proc.stdout
    leader = summary(shared_runs["leader"])["history"][0]
    assert summary(out)["history"][0] == leader  # the same offline policy, evaluated
    assert scalars(out, "augment"), "no augmentation round ran online"


# ------------------------------------------------------------------ what the key holds
KEYED = Path(__file__).with_name("offline_cache_keys.txt")


def _leaves(container: dict, prefix: str = "") -> Iterator[str]:
    for name, value in container.items():
        if isinstance(value, dict) and value:
            yield from _leaves(value, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}"


def test_every_config_key_is_classified_for_the_offline_cache(tmp_path, monkeypatch):
    """The keys a cache entry is keyed by, over every algorithm, env and critic, are the
    recorded ones: a key added to (or removed from) the config would otherwise change every
    key and orphan every cache entry written before it (it happened with
    ``compile.cudagraphs``)."""
    from torchrl_dual.recipe.settings.algos import ALGORITHMS
    from torchrl_dual.recipe.settings.minari_datasets import FAMILIES

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    envs = sorted(p.stem for p in (Path(RECIPE_CONFIG_DIR) / "env").glob("*.yaml"))
    for env in envs:  # stand-ins for the Minari data sets: what the config check looks for
        env_cfg = OmegaConf.create(
            {"env": OmegaConf.load(Path(RECIPE_CONFIG_DIR) / "env" / f"{env}.yaml")}
        )
        if env_cfg.env.kind in FAMILIES:
            from minari.storage import get_dataset_path

            (get_dataset_path(FAMILIES[env_cfg.env.kind].dataset_id(env_cfg.env)) / "data").mkdir(
                parents=True, exist_ok=True
            )
    runs = [(algo, ()) for algo in ALGORITHMS]
    runs += [("dual", (f"env={env}",)) for env in envs]
    runs += [("dual", (f"critic={critic}",)) for critic in ("calql", "so2")]
    keyed: set[str] = set()
    for algo, overrides in runs:
        cfg = compose_checked(
            RECIPE_CONFIG_DIR, [f"algo={algo}", *overrides, f"output_dir={tmp_path}"]
        )
        config = OmegaConf.to_container(cfg, resolve=True)
        keyed |= set(_leaves(offline_key_config(config, ALGORITHMS[algo].learner.online_keys)))
    recorded = set(KEYED.read_text().split())
    assert keyed == recorded, (
        f"config keys new to the offline-cache key: {sorted(keyed - recorded)}; gone from it: "
        f"{sorted(recorded - keyed)}. A new key the offline stages do not read belongs in "
        "offline_cache.ONLINE_KEYS (or the learner's online_keys); a key they read goes "
        f"into {KEYED.name}"
    )
