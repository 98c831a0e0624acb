"""``collector.num_envs`` (issue 40, item 3): several envs stepped as one batch.

The batched env (:func:`~torchrl_dual.envs.vectorized_env`) is env for env the kit's
online env: under the same actions, copy ``i`` seeded ``s + i`` steps, ends and resets
exactly as its own env seeded ``s + i`` (PointMaze with a shift, start cells and a reward
transform; Frozen-Lake with its slip shift; a Minari family with normalized observations),
episodes ending at different times. DUAL's exploration policy acts for each env of a
batch in one call as for that env alone. A DUAL run at ``collector.num_envs=4`` acts with one
policy call per batched step, stores every frame once as ``[4, T]`` batches, counts each
env's episodes apart (ids unique, each episode one contiguous trajectory of its env, its
``previous_*`` keys its own), and a run interrupted and resumed ends bitwise as the run
never interrupted. ``num_envs=1`` steps the run's env itself, as before.
"""

from __future__ import annotations

from types import SimpleNamespace

import pytest
import torch
from recipe_runner import WALL_CLOCK
from tensordict import TensorDict
from test_collectors import (
    FAST,
    assert_contiguous_episodes,
    assert_previous_keys_follow_trajectories,
)
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual.checkpoint import state_differences
from torchrl_dual.diffusion import TrajectoryDiffusion, TrajectoryLayout
from torchrl_dual.envs import vectorized_env
from torchrl_dual.modules import PlannerActor, TransitionModel, make_dual_policy
from torchrl_dual.recipe import CONFIG_DIR, O2ORun, compose_checked, run
from torchrl_dual.recipe.kits import build as env_kits

KEYS = (
    "observation",
    "action",
    "step_count",
    "previous_observation",
    "previous_action",
    "previous_valid",
    ("next", "observation"),
    ("next", "reward"),
    ("next", "terminated"),
    ("next", "truncated"),
    ("next", "done"),
    ("next", "step_count"),
)


def steps_alike(make_env, num_envs: int, steps: int, seed: int = 3) -> int:
    """Steps ``vectorized_env(make_env, num_envs)`` and ``num_envs`` single envs under the
    same random actions; asserts each step of copy ``i`` equals its single env's; returns
    how many episodes ended."""
    batched = vectorized_env(make_env, num_envs)
    singles = [make_env() for _ in range(num_envs)]
    batched.set_seed(seed)
    for i, env in enumerate(singles):
        env.set_seed(seed + i)
    td = batched.reset()
    tds = [env.reset() for env in singles]
    generator = torch.Generator().manual_seed(0)
    spec = singles[0].action_spec
    ended = 0
    for _ in range(steps):
        actions = spec.low + (spec.high - spec.low) * torch.rand(
            num_envs, *spec.shape, generator=generator
        )
        td["action"] = actions
        out, td = batched.step_and_maybe_reset(td)
        for i, env in enumerate(singles):
            tds[i]["action"] = actions[i]
            single, tds[i] = env.step_and_maybe_reset(tds[i])
            for key in KEYS:
                assert torch.equal(out[i][key], single[key]), (i, key)
        ended += int(out["next", "done"].sum())
    return ended


def test_dual_s_exploration_policy_acts_for_each_env_of_a_batch_as_for_it_alone():
    """One call on 4 envs' states: every member's mean and variance, the predicted state,
    d_t (0 where an env has just reset) and the executed std of each env are what a call on
    that env alone gives (up to the rounding of batched matrix products)."""
    torch.manual_seed(0)
    model = TrajectoryDiffusion(TrajectoryLayout(6, 2, 4), num_steps=1, hidden=32, depth=1)
    model.normalizer.fit(torch.randn(64, 6), torch.rand(64, 2) * 2 - 1)
    policy = make_dual_policy(
        PlannerActor(model),
        Bounded(-1.0, 1.0, shape=(2,)),
        transition_model=TransitionModel.frozen_copy(model),
        shift_weight=0.5,
    )
    policy[0].fit_laplace([TensorDict({"observation": torch.randn(64, 6)}, [64])])
    observation = torch.randn(4, 6)
    step = TensorDict(
        observation=observation,
        previous_observation=observation + 0.1 * torch.randn(4, 6),
        previous_action=torch.rand(4, 2) * 2 - 1,
        previous_valid=torch.tensor([[True], [False], [True], [True]]),
        batch_size=[4],
    )
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        batched = policy(step.clone())
        alone = torch.cat([policy(step[i : i + 1].clone()) for i in range(4)])
    keys = ("loc", "scale", "epistemic_variance", "expected_observation", "shift_distance")
    for key in (*keys, "exploration_scale"):
        torch.testing.assert_close(batched[key], alone[key], rtol=1e-5, atol=1e-5)
    assert batched["shift_distance"][1].item() == 0.0 < batched["shift_distance"][0].item()
    assert batched["action"].shape == (4, 2) and (batched["action"].abs() <= 1).all()


def compose(tmp_path, *overrides: str):
    return compose_checked(
        CONFIG_DIR, [f"output_dir={tmp_path / 'run'}", "budget=smoke", *overrides]
    )


@pytest.mark.parametrize(
    "overrides",
    [
        (
            "env=pointmaze_umaze",
            "env.max_episode_steps=10",
            "env.shift=rotation",
            "env.start_avoid_cells=[[3,1]]",
            "env.reward_scale=10",
            "env.reward_shift=-5",
        ),
        ("env=frozenlake", "env.shift=biased_slip"),
    ],
    ids=["pointmaze", "frozenlake"],
)
def test_each_env_of_the_batch_steps_as_its_own_env(overrides, tmp_path):
    cfg = compose(tmp_path, *overrides, "collector.num_envs=4")
    ended = steps_alike(lambda: env_kits.make_train_env(cfg), 4, 40)
    assert ended >= 6  # episodes end (and the envs reset) inside the run, not all at once


def test_a_minari_family_s_batch_steps_as_its_own_envs(tmp_path, monkeypatch):
    pytest.importorskip("h5py", reason="Minari's storage needs h5py")
    pytest.importorskip("minari")
    from torchrl_dual.data.minari_standins import write_standin_dataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    write_standin_dataset("mujoco/hopper/medium-v0", 4, 40)
    cfg = compose(tmp_path, "env=hopper", "env.max_episode_steps=30")
    data = env_kits.make_offline_dataset(cfg)  # the observation normalizer's statistics
    ended = steps_alike(lambda: env_kits.make_train_env(cfg, data), 3, 40)
    assert ended >= 3


def test_one_env_is_the_run_s_env_itself(tmp_path):
    cfg = compose(tmp_path, "env.max_episode_steps=15")
    assert cfg.collector.num_envs == 1
    env = env_kits.make_train_env(cfg)
    assert env_kits.make_collection_env(cfg, None, env) is env


# ----------------------------------------------------------------------------- a run
BATCHED = [*FAST, "collector.num_envs=4", "budget.checkpoint_every=60"]


@pytest.fixture(scope="module")
def batched_runs(tmp_path_factory):
    """DUAL on PointMaze at ``collector.num_envs=4``: interrupted at 60 frames and resumed,
    and the same run never interrupted; every collected batch is recorded as ``store``
    receives it, and the exploration policy's calls are counted."""
    cache = tmp_path_factory.mktemp("batched_data")
    out = tmp_path_factory.mktemp("batched")
    batches: list = []
    calls: list = []  # the batch size of each call
    original_store, original_init = O2ORun.store, O2ORun.__init__

    def store(self, batch):
        batches.append(batch.clone())
        return original_store(self, batch)

    def init(self, *args, **kwargs):
        original_init(self, *args, **kwargs)
        self.learner.exploration_policy.register_forward_pre_hook(
            lambda _, args: calls.append(tuple(args[0].batch_size))
        )

    def cfg(name, *extra):
        return compose_checked(
            CONFIG_DIR, [*BATCHED, f"output_dir={out / name}", f"data_cache_dir={cache}", *extra]
        )

    O2ORun.store, O2ORun.__init__ = store, init
    try:
        first = run(cfg("resumed", "interrupt_at_frames=60"))
        interrupted = first.state()
        resumed = run(cfg("resumed", "resume=true"))
        stored, policy_calls = list(batches), list(calls)
        whole = run(cfg("whole"))
    finally:
        O2ORun.store, O2ORun.__init__ = original_store, original_init
    return SimpleNamespace(
        interrupted=interrupted,
        resumed=resumed,
        whole=whole,
        batches=stored,
        policy_calls=policy_calls,
        offline_max=int(resumed.data.transitions["episode"].max()),
    )


def test_a_batched_run_stores_every_frame_once_as_num_envs_streams(batched_runs):
    final = batched_runs.resumed.state()
    assert (batched_runs.interrupted["frames"], final["frames"]) == (60, 120)
    assert [tuple(b.shape) for b in batched_runs.batches] == [(4, 5)] * 6
    online = final["online_data"]
    assert len(online) == 120
    # one policy call per batched step, for the 4 envs at once (and TorchRL's Collector
    # probes the policy once when it starts: 2 collectors, the first and the resumed run's)
    assert batched_runs.policy_calls == [(4,)] * (120 // 4 + 2)


def test_each_env_s_episodes_are_counted_apart(batched_runs):
    online = batched_runs.resumed.state()["online_data"]
    assert_contiguous_episodes(online)
    assert assert_previous_keys_follow_trajectories(batched_runs.batches) > 90
    ids = online["episode"]
    assert int(ids.min()) > batched_runs.offline_max
    # 4 envs, 30 steps each in two collectors of 15 (the resume is a cut point), episodes of
    # 15 steps: each env 2 episodes, 8 in all, none shared between envs
    assert ids.unique().numel() == 8
    for batch in batched_runs.batches:
        per_env = [set(batch[i]["collector", "traj_ids"].tolist()) for i in range(4)]
        assert all(a.isdisjoint(b) for j, a in enumerate(per_env) for b in per_env[j + 1 :])
    # one episode's frames come from one env: its frame count is its env's steps
    assert sorted(torch.bincount(ids - ids.min()).tolist()) == [15] * 8


def test_a_batched_run_resumes_bitwise(batched_runs):
    assert batched_runs.whole.frames == 120
    differ = state_differences(
        batched_runs.whole.state(), batched_runs.resumed.state(), ignore=WALL_CLOCK
    )
    assert differ == [], f"the resumed run differs at {differ[:10]}"
