"""ContinuousOneHotAction: the inverse hands the env the argmax of the policy's vector."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from torchrl_dual.envs import ContinuousOneHotAction, make_frozenlake_env


def test_inverse_maps_a_batch_of_vectors_to_the_one_hot_of_their_argmax():
    vectors = torch.rand(64, 4)
    out = ContinuousOneHotAction(4).inv(TensorDict({"action": vectors.clone()}, [64]))["action"]
    assert torch.equal(out, torch.nn.functional.one_hot(vectors.argmax(-1), 4))


def test_categorical_mode_hands_over_the_argmax_index():
    vectors = torch.randn(8, 5)
    t = ContinuousOneHotAction(5, categorical=True, low=-1.0)
    out = t.inv(TensorDict({"action": vectors.clone()}, [8]))["action"]
    assert torch.equal(out, vectors.argmax(-1))


def test_wrong_vector_size_raises_a_value_error():
    with pytest.raises(ValueError, match="size 4"):
        ContinuousOneHotAction(4).inv(TensorDict({"action": torch.rand(3)}))


def test_action_spec_is_a_float_box_whose_samples_cover_all_actions():
    env = make_frozenlake_env("4x4")
    spec = env.action_spec
    assert spec.dtype == torch.float32 and spec.shape == (4,)
    assert spec.space.low.tolist() == [0.0] * 4 and spec.space.high.tolist() == [1.0] * 4
    counts = torch.bincount(torch.stack([spec.rand() for _ in range(400)]).argmax(-1), minlength=4)
    assert (counts > 60).all()


def test_rollout_stores_the_policy_vector_not_the_env_one_hot():
    env = make_frozenlake_env("4x4", seed=0)
    rollout = env.rollout(5)
    assert not torch.equal(rollout["action"], rollout["action"].round())
