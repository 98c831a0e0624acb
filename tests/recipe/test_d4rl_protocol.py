"""``env.protocol=d4rl`` (the default of the Minari families) on data sets written here under
the published ids: D4RL's single-goal AntMaze task (data relabelled, online and evaluation
envs in the data's maze, score = 100 x success rate), D4RL's horizons and reference returns,
and the reward transforms of each critic's reference."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("h5py", reason="Minari's storage needs h5py: pip install 'minari[hdf5]'")
minari = pytest.importorskip("minari")

from recipe_runner import compose_smoke, standin_minari_datasets  # noqa: E402
from tensordict.nn import TensorDictModule  # noqa: E402

from torchrl_dual.data.minari_standins import UMAZE_MAP, write_standin_dataset  # noqa: E402
from torchrl_dual.data.transition_layout import validate_transitions  # noqa: E402
from torchrl_dual.envs.d4rl_antmaze import SingleGoalAntMaze  # noqa: E402
from torchrl_dual.recipe import run  # noqa: E402
from torchrl_dual.recipe.kits import build as env_kits  # noqa: E402
from torchrl_dual.recipe.kits.minari_families import minari_evaluator, minari_gym_env  # noqa: E402
from torchrl_dual.recipe.settings.minari_datasets import FAMILIES  # noqa: E402
from torchrl_dual.recipe.settings.references import REWARD_TRANSFORMS  # noqa: E402

ANTMAZE_ID, HOPPER_ID, PEN_ID = (
    "D4RL/antmaze/umaze-v1",
    "mujoco/hopper/medium-v0",
    "D4RL/pen/cloned-v2",
)
GOAL = np.array([-3.25, 4.75])


FAST = (
    "budget.offline_updates=5",
    "online.utd_ratio=0.2",
    "budget.online_frames=30",
    "budget.frames_per_batch=30",
    "budget.eval_every=30",
    "budget.checkpoint_every=30",
    "budget.eval_episodes=1",
    "budget.laplace_refit_every=5",
    "env.max_episode_steps=20",
)
"""A run of a few updates and one online batch: the end-to-end tests' budget."""


@pytest.fixture(scope="module")
def minari_path(tmp_path_factory):
    root = tmp_path_factory.mktemp("minari_datasets")
    with standin_minari_datasets(
        root, {ANTMAZE_ID: (3, 30), HOPPER_ID: (3, 30), PEN_ID: (2, 30)}
    ) as path:
        yield path


def compose(tmp_path: Path, *overrides: str):
    return compose_smoke(tmp_path, *overrides)


def test_antmaze_data_are_d4rl_s_task_relabelled(minari_path, tmp_path):
    """29 numbers without the goal; reward 1 within 0.5 of D4RL's goal (then IQL's r - 1),
    terminal there; states normalized after the relabelling."""
    cfg = compose(tmp_path, "env=antmaze", "env.normalize_observations=false")
    data = env_kits.make_offline_dataset(cfg)
    assert data.metadata["observation_keys"] == ["achieved_goal", "observation"]
    assert data.metadata["protocol"] == "d4rl" and data.metadata["task_goal"] == GOAL.tolist()
    assert (data.reference_min, data.reference_max) == (0.0, 1.0)
    episodes = list(minari.load_dataset(ANTMAZE_ID).iterate_episodes())
    next_xy = np.concatenate([ep.observations["achieved_goal"][1:] for ep in episodes])
    reached = np.linalg.norm(next_xy - GOAL, axis=1) <= 0.5
    td = data.transitions
    assert td["observation"].shape[-1] == 29
    assert np.allclose(td["next", "observation"][:, :2].numpy(), next_xy, atol=1e-6)
    assert td["next", "reward"].squeeze(-1).tolist() == (reached.astype(np.float32) - 1).tolist()
    assert td["next", "terminated"].squeeze(-1).tolist() == reached.tolist()
    validate_transitions(td)


def test_relabelled_data_reaching_the_goal_end_their_episode_there(minari_path, tmp_path):
    """The stand-in's random ant never reaches the goal; moving D4RL's goal onto a visited
    place shows the kit's relabelling splits the data's episodes at every success."""
    from torchrl_dual.recipe.kits import d4rl_protocol

    cfg = compose(tmp_path, "env=antmaze", "env.normalize_observations=false")
    task = d4rl_protocol.data_protocol(cfg.env).antmaze_task
    episodes = list(minari.load_dataset(ANTMAZE_ID).iterate_episodes())
    visited = episodes[1].observations["achieved_goal"][12]
    moved = type(task)(**{**task.__dict__, "goal": visited})
    patch = pytest.MonkeyPatch()
    patch.setattr(d4rl_protocol, "_antmaze_task", lambda *args: moved)
    try:
        data = env_kits.make_offline_dataset(cfg)
    finally:
        patch.undo()
    td = data.transitions
    next_xy = np.concatenate([ep.observations["achieved_goal"][1:] for ep in episodes])
    reached = np.linalg.norm(next_xy - visited, axis=1) <= 0.5
    assert reached.sum() >= 2
    assert td["next", "terminated"].squeeze(-1).tolist() == reached.tolist()
    done = td["next", "done"].squeeze(-1)
    assert td["episode"].unique().numel() == int(done.sum()) > len(episodes)
    validate_transitions(td)  # a new episode after every done transition


def test_online_and_evaluation_envs_play_the_task_in_the_data_s_maze(minari_path, tmp_path):
    cfg = compose(tmp_path, "env=antmaze")
    data = env_kits.make_offline_dataset(cfg)
    for eval_env in (False, True):
        env = minari_gym_env(cfg, data, eval_env=eval_env, shifted=True)
        assert isinstance(env.env, SingleGoalAntMaze)
        assert env.unwrapped.maze.maze_map == UMAZE_MAP  # not Minari's turned eval map
        assert env.spec.max_episode_steps == 700  # D4RL's antmaze-umaze
        assert env.observation_space.shape == (29,)
    online = env_kits.make_train_env(cfg, data)
    rollout = online.rollout(5)
    assert rollout["observation"].shape == (5, 29)
    assert torch.all(rollout["next", "reward"] == -1.0)  # r = 0 far from the goal, IQL's r - 1


def test_the_ant_s_clock_key_sets_the_time_limit_in_simulated_seconds(minari_path, tmp_path):
    """The data's ant steps 0.05 s (timestep 0.01 x frame skip 5), D4RL's 0.1 s (0.02 x 5):
    env.horizon_seconds=d4rl gives D4RL's 70 s of umaze, 1400 steps; a number is seconds;
    env.max_episode_steps still wins; unset, D4RL's 700 steps (35 s here)."""
    cases = {(): 700, ("env.horizon_seconds=d4rl",): 1400, ("env.horizon_seconds=10",): 200}
    cases[("env.horizon_seconds=d4rl", "env.max_episode_steps=50")] = 50
    data = env_kits.make_offline_dataset(compose(tmp_path, "env=antmaze"))
    for overrides, steps in cases.items():
        cfg = compose(tmp_path, "env=antmaze", *overrides)
        for eval_env in (False, True):
            env = minari_gym_env(cfg, data, eval_env=eval_env, shifted=False)
            assert env.spec.max_episode_steps == steps, overrides
            assert env.unwrapped.ant_env.dt == pytest.approx(0.05)
            env.close()


def test_goal_noise_redraws_d4rl_s_goal_in_its_square_at_each_reset(minari_path, tmp_path):
    data = env_kits.make_offline_dataset(compose(tmp_path, "env=antmaze"))
    for noise in (False, True):
        cfg = compose(tmp_path, "env=antmaze", f"env.goal_noise={str(noise).lower()}")
        env = minari_gym_env(cfg, data, eval_env=True, shifted=False)
        goals = np.array([env.env.reset(seed=s)[0]["desired_goal"] for s in range(20)])
        # D4RL's square: the G cell's corner (-4, 4) + U(0, 1) + U(0, 0.5) per axis
        assert np.all(goals >= GOAL - 0.75) and np.all(goals <= GOAL + 0.75)
        assert (goals.std(0) > 0.1).all() == noise and (goals.std(0) == 0).all() != noise


def test_a_random_policy_scores_0_in_the_kit_s_evaluator(minari_path, tmp_path):
    cfg = compose(tmp_path, "env=antmaze", "budget.eval_episodes=3")
    data = env_kits.make_offline_dataset(cfg)
    generator = torch.Generator().manual_seed(0)
    policy = TensorDictModule(
        lambda obs: torch.rand(obs.shape[0], 8, generator=generator) * 2 - 1,
        in_keys=["observation"],
        out_keys=["action"],
    )
    result = minari_evaluator(cfg, data)(policy)
    assert result["return"] == 0.0 and result["normalized_score"] == 0.0


@pytest.mark.parametrize("critic, scale, shift", [("iql", 1.0, -1.0), ("calql", 10.0, -5.0)])
def test_each_critic_trains_on_its_reference_s_antmaze_reward(
    minari_path, tmp_path, critic, scale, shift
):
    algo = {"iql": "iql", "calql": "calql"}[critic]
    data = env_kits.make_offline_dataset(compose(tmp_path, "env=antmaze", f"algo={algo}"))
    assert (data.metadata["reward_scale"], data.metadata["reward_shift"]) == (scale, shift)
    assert torch.all(data.transitions["next", "reward"] == shift)  # never reached: r = 0
    explicit = compose(
        tmp_path, "env=antmaze", f"algo={algo}", "env.reward_scale=2", "env.reward_shift=0"
    )
    data = env_kits.make_offline_dataset(explicit)
    assert (data.metadata["reward_scale"], data.metadata["reward_shift"]) == (2.0, 0.0)


def test_every_family_has_a_reward_transform_for_every_critic():
    from torchrl_dual.recipe.settings.algos import ALGORITHMS

    critics = {c for algorithm in ALGORITHMS.values() for c in algorithm.settings.critics}
    assert set(REWARD_TRANSFORMS) == set(FAMILIES)
    for kind, table in REWARD_TRANSFORMS.items():
        assert critics <= set(table), kind


@pytest.mark.parametrize(
    "overrides, critic_depth, lagrange_gap, sparse_failure, min_q_weight, actor_depth, normalize",
    [
        (("env=antmaze", "algo=calql"), 4, 0.8, -5.0, 5.0, 2, False),  # the authors' AntMaze
        (("env=adroit", "algo=calql"), 3, None, None, 1.0, 3, False),  # CORL's cloned Adroit
        (("env=hopper", "algo=calql"), 2, None, None, 5.0, 2, True),  # no reference: defaults
        (("env=pointmaze_umaze", "algo=calql"), 2, None, None, 5.0, 2, None),  # local data
        (
            ("env=antmaze", "algo=calql", "critic.depth=2", "critic.lagrange_gap=null"),
            2,
            None,
            -5.0,
            5.0,
            2,
            False,
        ),  # the command line wins
    ],
)
def test_cal_ql_takes_its_reference_s_settings_on_each_family(
    minari_path,
    tmp_path,
    overrides,
    critic_depth,
    lagrange_gap,
    sparse_failure,
    min_q_weight,
    actor_depth,
    normalize,
):
    cfg = compose(tmp_path, *overrides)
    assert cfg.critic.depth == critic_depth and cfg.critic.lagrange_gap == lagrange_gap
    assert cfg.critic.sparse_failure_reward == sparse_failure
    assert cfg.critic.min_q_weight == min_q_weight and cfg.actor.depth == actor_depth
    assert cfg.env.get("normalize_observations") == normalize


def test_the_iql_critic_keeps_corl_s_settings_and_dual_on_cal_ql_takes_cal_ql_s(
    minari_path, tmp_path
):
    iql = compose(tmp_path, "env=antmaze", "algo=iql")
    assert iql.env.normalize_observations is True and iql.critic.expectile == 0.9
    dual = compose(tmp_path, "env=antmaze", "algo=dual", "critic=calql")
    assert (dual.critic.depth, dual.critic.lagrange_gap) == (4, 0.8)
    assert dual.env.normalize_observations is False


def test_cal_ql_on_antmaze_trains_its_lagrange_multiplier_end_to_end(minari_path, tmp_path):
    result = run(compose(tmp_path, "env=antmaze", "algo=calql", "num_threads=1", *FAST))
    loss = result.learner.critic.loss
    assert loss.with_lagrange and loss.target_action_gap == 0.8
    assert float(loss.log_alpha_prime.detach()) != 1.0  # stepped from the references' 1.0
    linear = [k for k in loss.qvalue_network_params.keys(True, True) if k[-1] == "weight"]
    assert len(linear) == 4 + 1  # 4 hidden layers and the output
    assert torch.isfinite(result.learner.update(result.replay.sample())["alpha_prime"])


def test_pen_runs_at_d4rl_s_100_step_horizon(minari_path, tmp_path):
    cfg = compose(tmp_path, "env=adroit")
    data = env_kits.make_offline_dataset(cfg)
    assert minari_gym_env(cfg, data, eval_env=True, shifted=False).spec.max_episode_steps == 100
    minari_cfg = compose(tmp_path, "env=adroit", "env.protocol=minari")
    assert (
        minari_gym_env(minari_cfg, data, eval_env=True, shifted=False).spec.max_episode_steps == 200
    )
    assert (data.reference_min, data.reference_max) == (96.262799, 3076.8331017826877)


def _drop_the_pen(env):
    """Puts the pen 0.2 below its start (its first slide joint points down in the world);
    returns the unwrapped ``AdroitHandPen``."""
    pen = env.unwrapped
    qpos, qvel = pen.data.qpos.copy(), pen.data.qvel.copy()
    qpos[24] += 0.2
    pen.set_state(qpos, qvel)
    return pen


def test_a_dropped_pen_ends_the_episode_as_d4rl_s_does(minari_path, tmp_path):
    """D4RL's pen_v0.py: done once the pen's height is below 0.075 (with the -5 penalty,
    which Gymnasium-Robotics' dense reward keeps); protocol=minari keeps the data set's
    env, which never terminates."""
    cfg = compose(tmp_path, "env=adroit")
    data = env_kits.make_offline_dataset(cfg)
    for protocol, ends in (("d4rl", True), ("minari", False)):
        run_cfg = compose(tmp_path, "env=adroit", f"env.protocol={protocol}")
        for eval_env in (False, True):
            env = minari_gym_env(run_cfg, data, eval_env=eval_env, shifted=False)
            env.reset(seed=0)
            still = np.zeros(env.action_space.shape, np.float32)
            _, _, terminated, _, _ = env.step(still)
            assert not terminated  # the pen starts in the hand, at height 0.25
            pen = _drop_the_pen(env)
            _, reward, terminated, truncated, info = env.step(still)
            assert pen.data.xpos[pen.obj_body_id][2] < 0.075
            assert reward < -4  # D4RL's drop penalty, -5 plus the orientation term
            assert (terminated, truncated) == (ends, False), (protocol, eval_env)
            assert info.get("pen_dropped", False) == ends
            env.close()


def test_locomotion_scores_with_d4rl_s_references(minari_path, tmp_path):
    result = run(compose(tmp_path, "env=hopper", "algo=iql", "num_threads=1", *FAST))
    for h in result.history:
        assert math.isfinite(h["normalized_score"])
        assert h["normalized_score"] == pytest.approx(
            100 * (h["return"] + 20.272305) / (3234.3 + 20.272305)
        )


@pytest.mark.parametrize(
    "dataset, goal_cell, goal",
    [
        ("umaze", (1, 1), (-3.25, 4.75)),
        ("umaze-diverse", (1, 1), (-3.25, 4.75)),
        ("medium-play", (6, 6), (10.75, -10.75)),
        ("medium-diverse", (6, 6), (10.75, -10.75)),
        ("large-play", (7, 9), (14.75, -12.75)),
        ("large-diverse", (7, 9), (14.75, -12.75)),
    ],
)
def test_d4rl_s_task_is_placed_in_every_minari_antmaze(
    tmp_path, monkeypatch, dataset, goal_cell, goal
):
    """The generation scripts' mazes (stand-ins): D4RL's goal cell and goal in each."""
    from torchrl_dual.recipe.kits import d4rl_protocol

    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path))
    dataset_id = f"D4RL/antmaze/{dataset}-v1"
    write_standin_dataset(dataset_id, 1, 5)
    d4rl_protocol._antmaze_task.cache_clear()
    task = d4rl_protocol._antmaze_task(dataset_id, dataset)
    d4rl_protocol._antmaze_task.cache_clear()
    assert task.goal_cell == goal_cell and task.goal.tolist() == list(goal)
    assert task.reset_cell in ((1, 1), (3, 1))
