"""ENV_KITS and ``env.shift``: the shift reaches the online env and the evaluator, never
the offline data (whose cache entry is the same with and without it), and bad shift
values fail before anything runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict.nn import TensorDictModule

import torchrl_dual.data.frozenlake_dataset as frozenlake_dataset
from torchrl_dual.envs import (
    biased_slip_table,
    frozenlake_mdp,
    frozenlake_optimal_policy,
    frozenlake_success_probability,
)
from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked
from torchrl_dual.recipe.kits import build as env_kits
from torchrl_dual.recipe.kits import pointmaze as pointmaze_kit


def compose(tmp_path: Path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        [
            f"output_dir={tmp_path / 'run'}",
            f"data_cache_dir={tmp_path / 'cache'}",
            "budget=smoke",
            *overrides,
        ],
    )


FROZENLAKE = ("env=frozenlake", "env.map_name=8x8", "budget.dataset_transitions=3000")


# ----------------------------------------------------------------------------- offline data
def test_frozenlake_offline_data_is_the_unshifted_cache_entry_even_with_a_shift(
    tmp_path, monkeypatch
):
    plain = env_kits.make_offline_dataset(compose(tmp_path, *FROZENLAKE))
    entries = sorted(p.name for p in (tmp_path / "cache").iterdir())

    def regenerate(*args, **kwargs):
        raise AssertionError("a shift must not change the data's cache entry")

    monkeypatch.setattr(frozenlake_dataset, "generate_frozenlake_dataset", regenerate)
    shifted = env_kits.make_offline_dataset(compose(tmp_path, *FROZENLAKE, "env.shift=biased_slip"))
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == entries
    for key in ("observation", "action", ("next", "observation")):
        assert torch.equal(plain.transitions[key], shifted.transitions[key])
    # the data holds slips that the biased slip makes impossible: it comes from the
    # unshifted dynamics (the offline success rate 3/4, slips to both sides)
    s = shifted.transitions["observation"].argmax(-1).numpy()
    a = shifted.transitions["action"].argmax(-1).numpy()
    s_next = shifted.transitions["next", "observation"].argmax(-1).numpy()
    assert (frozenlake_mdp("8x8", 3 / 4, "biased_slip").transitions[s, a, s_next] == 0).sum() > 50
    assert (frozenlake_mdp("8x8", 3 / 4).transitions[s, a, s_next] > 0).all()


@pytest.mark.parametrize(
    "shift", ["env.shift=rotation", "env.shift=damping", "env.shift=mass env.shift_scale=3"]
)
def test_pointmaze_offline_data_is_requested_exactly_as_without_a_shift(
    shift, tmp_path, monkeypatch
):
    calls = []
    monkeypatch.setattr(
        pointmaze_kit,
        "load_or_generate_maze_dataset",
        lambda *args, **kwargs: calls.append((args, kwargs)),
    )
    kit = env_kits.ENV_KITS["pointmaze"]
    kit.load_data(compose(tmp_path))
    kit.load_data(compose(tmp_path, *shift.split()))
    assert len(calls) == 2 and calls[0] == calls[1]
    assert "shift" not in str(calls[0])


def test_env_goal_cell_reaches_the_data_the_train_env_and_the_evaluator(tmp_path, monkeypatch):
    """``env.goal_cell`` is one setting of the task: the data, the online env and the
    evaluation episodes all have their goal in that cell."""
    cfg = compose(tmp_path, "env.goal_cell=[3,1]", "budget.dataset_transitions=300")
    data = env_kits.make_offline_dataset(cfg)
    assert data.metadata["goal_cell"] == [3, 1]
    goal = data.transitions["observation"][0, 4:]
    assert (goal < -0.5).all()  # umaze cell (3, 1): the bottom-left one
    env = env_kits.make_train_env(cfg)
    for episode in range(6):  # each reset draws a new start (and, without it, a new goal)
        assert (env.reset()["observation"][4:] < -0.5).all(), episode
    seen = []
    real = pointmaze_kit.make_pointmaze_gym_env
    monkeypatch.setattr(
        pointmaze_kit,
        "make_pointmaze_gym_env",
        lambda *args, **kwargs: seen.append(kwargs.get("goal_cell")) or real(*args, **kwargs),
    )
    still = TensorDictModule(
        lambda obs: torch.zeros(*obs.shape[:-1], 2), in_keys=["observation"], out_keys=["action"]
    )
    evaluate = env_kits.make_evaluator(
        compose(tmp_path, "env.goal_cell=[3,1]", "budget.eval_episodes=1"), data
    )
    assert evaluate(still)["return"] >= 0.0
    assert seen and set(map(tuple, seen)) == {(3, 1)}


# ----------------------------------------------------------------------------- online env
def _velocity_after_one_step(env) -> torch.Tensor:
    td = env.reset()
    td["action"] = torch.tensor([0.8, -0.3])
    return env.step(td)["next", "observation"][2:4]


def test_the_pointmaze_train_env_carries_the_shift(tmp_path):
    plain = _velocity_after_one_step(env_kits.make_train_env(compose(tmp_path)))
    for shift in ("rotation", "mass"):
        cfg = compose(tmp_path, f"env.shift={shift}")
        assert not torch.allclose(plain, _velocity_after_one_step(env_kits.make_train_env(cfg)))


def test_the_frozenlake_train_env_carries_the_shift(tmp_path):
    cfg = compose(tmp_path, *FROZENLAKE, "env.shift=biased_slip")
    env = env_kits.make_train_env(cfg)
    from gymnasium.envs.toy_text.frozen_lake import FrozenLakeEnv

    rate = cfg.env.online_success_rate
    expected = biased_slip_table(FrozenLakeEnv(map_name="8x8", success_rate=rate).P, rate)
    assert env.base_env._env.unwrapped.P == expected


# ----------------------------------------------------------------------------- evaluator
class _Scores:
    """Stands in for the offline data set: its normalized score is the return itself."""

    @staticmethod
    def normalized_score(value: float) -> float:
        return 100 * value


def _lookup_policy(actions: np.ndarray) -> TensorDictModule:
    table = torch.eye(4)[torch.as_tensor(actions)]
    return TensorDictModule(lambda obs: obs @ table, in_keys=["observation"], out_keys=["action"])


def test_the_frozenlake_evaluator_scores_under_the_shift_and_without_it(tmp_path):
    offline = frozenlake_optimal_policy("8x8", 3 / 4)
    cfg = compose(tmp_path, *FROZENLAKE, "env.shift=biased_slip")
    result = env_kits.make_evaluator(cfg, _Scores())(_lookup_policy(offline))
    shifted = frozenlake_success_probability(offline, "8x8", 2 / 3, shift="biased_slip")
    plain = frozenlake_success_probability(offline, "8x8", 2 / 3)
    assert result["return"] == pytest.approx(shifted) and shifted < 0.01
    assert result["return_unshifted"] == pytest.approx(plain) and plain > 0.9
    assert result["normalized_score"] == pytest.approx(100 * shifted)
    assert result["normalized_score_unshifted"] == pytest.approx(100 * plain)
    unshifted = env_kits.make_evaluator(compose(tmp_path, *FROZENLAKE), _Scores())
    assert set(unshifted(_lookup_policy(offline))) == {"return", "normalized_score"}


def test_the_pointmaze_evaluator_runs_shifted_envs_and_reports_the_unshifted_score(
    tmp_path, monkeypatch
):
    made = []
    real = pointmaze_kit.make_pointmaze_gym_env

    def recording(*args, **kwargs):
        made.append(kwargs.get("shift", "none"))
        return real(*args, **kwargs)

    monkeypatch.setattr(pointmaze_kit, "make_pointmaze_gym_env", recording)
    policy = TensorDictModule(
        lambda obs: torch.ones(*obs.shape[:-1], 2), in_keys=["observation"], out_keys=["action"]
    )
    overrides = ("env.max_episode_steps=20", "budget.eval_episodes=2")
    cfg = compose(tmp_path, *overrides, "env.shift=rotation", "env.shift_angle=90")
    result = env_kits.make_evaluator(cfg, _Scores())(policy)
    assert made == ["rotation"] * 2 + ["none"] * 2
    assert {"return", "return_std", "normalized_score", "normalized_score_unshifted"} <= set(result)
    made.clear()
    result = env_kits.make_evaluator(compose(tmp_path, *overrides), _Scores())(policy)
    assert made == ["none"] * 2
    assert "normalized_score_unshifted" not in result


# ----------------------------------------------------------------------------- config errors
ERRORS = [
    (
        "env.shift=wind",
        "env.shift=wind: unknown option; choose one of none, rotation, damping, mass",
    ),
    (
        "env=frozenlake env.shift=rotation",
        "env.shift=rotation: unknown option; choose one of none, biased_slip, biased_slip_cw",
    ),
    ("env.shift_angle=200", "env.shift_angle=200: must lie in [-180, 180]"),
    ("env.shift_scale=0", "env.shift_scale=0: must be null or a number in (0, 1000]"),
    ("env.shift_scale=-2.5", "env.shift_scale=-2.5: must be null or a number in (0, 1000]"),
    ("env=frozenlake env.shift_angle=30", "unknown key 'env.shift_angle'"),
    ("env.goal_cell=[2,1]", "env.goal_cell=[2, 1]: goal_cell [2, 1] is not an open cell of"),
    ("env.goal_cell=3", "env.goal_cell=3: must be null or a list of integers >= 0"),
]


@pytest.mark.parametrize(("overrides", "message"), ERRORS, ids=[e[0] for e in ERRORS])
def test_a_bad_shift_fails_naming_the_key_the_value_and_what_is_allowed(
    overrides, message, tmp_path
):
    with pytest.raises(ConfigError) as err:
        compose(tmp_path, *overrides.split())
    assert str(err.value).startswith(message)


def test_valid_shift_settings_compose(tmp_path):
    cfg = compose(tmp_path, "env.shift=damping", "env.shift_scale=50")
    assert (cfg.env.shift, cfg.env.shift_angle, cfg.env.shift_scale) == ("damping", 60, 50)
    assert compose(tmp_path).env.shift == "none"
    assert compose(tmp_path, "env=frozenlake", "env.shift=biased_slip_cw").env.shift == (
        "biased_slip_cw"
    )


def test_env_data_avoid_cells_reaches_the_data_only(tmp_path):
    """``env.data_avoid_cells`` shapes the offline data (issue 29); the online env and the
    evaluation keep the whole maze. A wall or an outside cell is a config error."""
    cfg = compose(
        tmp_path, "env.goal_cell=[3,1]", "env.data_avoid_cells=[[3,1]]",
        "budget.dataset_transitions=300",
    )  # fmt: skip
    data = env_kits.make_offline_dataset(cfg)
    assert data.metadata["avoid_cells"] == [[3, 1]]
    assert data.metadata["reward_fraction"] == 0.0
    with pytest.raises(ConfigError, match="env.data_avoid_cells"):
        compose(tmp_path, "env.data_avoid_cells=[[0,0]]")
    with pytest.raises(ConfigError, match=r"\[row, col\] cells"):
        compose(tmp_path, "env.data_avoid_cells=[3,1]")
