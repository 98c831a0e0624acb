"""PointMaze's ``env.reward_scale`` / ``env.reward_shift`` (e.g. Cal-QL's sparse-maze
``10 r - 5``): the offline data and the online env train on the transformed reward, the
evaluation scores the env's own, and the identity changes no offline-cache key."""

from __future__ import annotations

import torch
from omegaconf import OmegaConf

from torchrl_dual.recipe import CONFIG_DIR, compose_checked
from torchrl_dual.recipe.kits import build
from torchrl_dual.recipe.o2o.offline_cache import offline_key_config


def compose(tmp_path, *overrides: str):
    return compose_checked(
        CONFIG_DIR,
        ["budget=smoke", f"output_dir={tmp_path}", f"data_cache_dir={tmp_path}", *overrides],
    )


def test_data_and_online_env_carry_the_transform_and_the_score_does_not(tmp_path):
    plain_cfg = compose(tmp_path, "algo=calql")
    cfg = compose(tmp_path, "algo=calql", "env.reward_scale=10", "env.reward_shift=-5")
    plain, data = build.make_offline_dataset(plain_cfg), build.make_offline_dataset(cfg)
    raw = plain.transitions["next", "reward"]
    assert set(raw.unique().tolist()) == {0.0, 1.0}
    assert torch.equal(data.transitions["next", "reward"], 10 * raw - 5)
    assert (data.reference_min, data.reference_max) == (plain.reference_min, plain.reference_max)
    for env_cfg, expected in ((plain_cfg, 0.0), (cfg, -5.0)):
        env = build.make_train_env(env_cfg, data)
        env.set_seed(0)
        assert torch.all(env.rollout(5)["next", "reward"] == expected)  # far from the goal


def test_the_reward_transform_is_part_of_the_offline_cache_key(tmp_path):
    key = offline_key_config(OmegaConf.to_container(compose(tmp_path), resolve=True))
    assert (key["env"]["reward_scale"], key["env"]["reward_shift"]) == (1.0, 0.0)
    other = compose(tmp_path, "env.reward_shift=-1")
    other = offline_key_config(OmegaConf.to_container(other, resolve=True))
    assert other["env"]["reward_shift"] == -1.0 and other != key
