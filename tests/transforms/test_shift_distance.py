"""Tests of the env-side shift signal d_t (DUAL Eq. 10) on a tiny env with a dynamics shift."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchrl_dual.modules.shift_aware import ShiftAwareNoise
from torchrl_dual.transforms import ShiftDistance

SHIFT_STEP = 5  # the dynamics change from this env step on
HORIZON = 10
DRIFT = (0.6, 0.8)  # ‖drift‖ = 1, so d jumps from 0 to exactly 1
LOC, SCALE, WEIGHT = 0.3, 0.1, 0.5


class DriftPointEnv(EnvBase):
    """2-D point ``s' = s + a``; from step ``SHIFT_STEP`` on ``s' = s + a + drift``."""

    def __init__(self, batch_size=(), horizon: int = HORIZON):
        super().__init__(batch_size=torch.Size(batch_size))
        shape = (*self.batch_size, 2)
        self.observation_spec = Composite(observation=Unbounded(shape=shape), shape=self.batch_size)
        self.action_spec = Bounded(-5.0, 5.0, shape=shape)
        self.reward_spec = Unbounded(shape=(*self.batch_size, 1))
        flag = Categorical(2, shape=(*self.batch_size, 1), dtype=torch.bool)
        self.done_spec = Composite(
            done=flag, terminated=flag.clone(), truncated=flag.clone(), shape=self.batch_size
        )
        self.horizon = horizon
        self._state = torch.zeros(shape)
        self._t = 0

    def _reset(self, tensordict):
        self._t = 0
        self._state = torch.zeros((*self.batch_size, 2))
        done = torch.zeros((*self.batch_size, 1), dtype=torch.bool)
        return TensorDict(
            observation=self._state.clone(),
            done=done,
            terminated=done.clone(),
            truncated=done.clone(),
            batch_size=self.batch_size,
        )

    def _step(self, tensordict):
        drift = torch.tensor(DRIFT) if self._t >= SHIFT_STEP else torch.zeros(2)
        self._state = self._state + tensordict["action"] + drift
        self._t += 1
        done = torch.full((*self.batch_size, 1), self._t >= self.horizon)
        return TensorDict(
            observation=self._state.clone(),
            reward=-self._state.norm(dim=-1, keepdim=True),
            done=done,
            terminated=torch.zeros_like(done),
            truncated=done.clone(),
            batch_size=self.batch_size,
        )

    def _set_seed(self, seed):
        torch.manual_seed(seed)


def make_policy(action_spec, shift_weight: float = WEIGHT) -> TensorDictSequential:
    """A fake actor with fixed loc/scale, then Eq. 10 noise with the ORIGINAL dynamics."""

    def fake_actor(observation):
        loc = torch.full_like(observation, LOC)
        return loc, torch.full_like(observation, SCALE), loc.clone()

    actor = TensorDictModule(fake_actor, ["observation"], ["loc", "scale", "action"])
    noise = ShiftAwareNoise(lambda s, a: s + a, action_spec, shift_weight)
    return TensorDictSequential(actor, noise)


def make_env(batch_size=()) -> TransformedEnv:
    return TransformedEnv(DriftPointEnv(batch_size), ShiftDistance())


def test_specs_declare_shift_distance_and_random_actions_give_zero():
    env = make_env((3,))
    spec = env.observation_spec["shift_distance"]
    assert spec.shape == (3, 1) and spec.dtype == torch.float32
    check_env_specs(env)  # random actions, no prediction in the root: d = 0
    rollout = env.rollout(4)
    assert (rollout["next", "shift_distance"] == 0).all()


def test_reset_writes_zero_distance():
    env = make_env((4,))
    policy = make_policy(env.action_spec)
    rollout = env.rollout(HORIZON, policy)
    assert (rollout["next", "shift_distance"][:, -1] > 0.5).all()
    td = env.reset()
    assert td["shift_distance"].shape == (4, 1)
    assert td["shift_distance"].dtype == torch.float32
    assert (td["shift_distance"] == 0).all()


def test_distance_jumps_at_dynamics_change_and_action_spread_follows():
    torch.manual_seed(0)
    env = make_env((2000,))
    rollout = env.rollout(HORIZON, make_policy(env.action_spec), break_when_any_done=False)
    d_next = rollout["next", "shift_distance"].squeeze(-1)  # [envs, time]
    # d = ‖ŝ - s'‖: 0 while the model is right, ‖drift‖ = 1 once the dynamics drift.
    torch.testing.assert_close(d_next[:, :SHIFT_STEP], torch.zeros(2000, SHIFT_STEP))
    torch.testing.assert_close(
        d_next[:, SHIFT_STEP:], torch.ones(2000, HORIZON - SHIFT_STEP), atol=1e-5, rtol=0
    )
    # The policy reads d_{t} at the next step: the action at step t uses d from step t-1.
    assert (rollout["shift_distance"][:, 0] == 0).all()
    torch.testing.assert_close(
        rollout["shift_distance"][:, 1:], rollout["next", "shift_distance"][:, :-1]
    )
    # Spread: sqrt(σ²) up to and including the change step, sqrt(σ² + λ·1) afterwards.
    noise = rollout["action"] - LOC
    before = noise[:, : SHIFT_STEP + 1].std()
    after = noise[:, SHIFT_STEP + 1 :].std()
    expected_after = (SCALE**2 + WEIGHT * 1.0) ** 0.5
    assert before == pytest.approx(SCALE, rel=0.03)
    assert after == pytest.approx(expected_after, rel=0.03)
    assert noise.mean().abs() < 0.02
    torch.testing.assert_close(
        rollout["exploration_scale"][:, SHIFT_STEP + 1 :],
        torch.full((2000, HORIZON - SHIFT_STEP - 1, 2), expected_after),
    )


def test_collector_stores_executed_noisy_action_and_shift_distance():
    torch.manual_seed(1)
    env = make_env((4,))
    collector = Collector(
        env,
        make_policy(env.action_spec),
        frames_per_batch=4 * 2 * HORIZON,  # two episodes per env
        total_frames=4 * 2 * HORIZON,
        auto_register_policy_transforms=False,
    )
    data = next(iter(collector))
    collector.shutdown()
    assert data.shape == (4, 2 * HORIZON)
    assert data["next", "shift_distance"].shape == (4, 2 * HORIZON, 1)
    assert (data["action"] != LOC).all()  # noisy, not the actor's loc
    # The env moved by the stored action: s' = s + a (+ drift after the change).
    drift = torch.zeros(HORIZON, 2)
    drift[SHIFT_STEP:] = torch.tensor(DRIFT)
    drift = drift.repeat(2, 1)
    moved = data["observation"] + data["action"]
    torch.testing.assert_close(data["next", "observation"], moved + drift)
    torch.testing.assert_close(data["predicted_observation"], moved)
    d = data["next", "shift_distance"].squeeze(-1)
    torch.testing.assert_close(d, drift.norm(dim=-1).expand(4, -1), atol=1e-5, rtol=0)
    # The policy saw d from the previous step, and 0 after each reset.
    d_seen = data["shift_distance"].squeeze(-1)
    assert (d_seen[:, [0, HORIZON]] == 0).all()
    torch.testing.assert_close(d_seen[:, 1:HORIZON], d[:, : HORIZON - 1])
    torch.testing.assert_close(d_seen[:, HORIZON + 1 :], d[:, HORIZON:-1])


def test_forward_recomputes_distance_on_stored_transitions():
    env = make_env((3,))
    rollout = env.rollout(HORIZON, make_policy(env.action_spec))
    stored = rollout["next", "shift_distance"].clone()
    recomputed = ShiftDistance()(rollout.exclude(("next", "shift_distance")))
    torch.testing.assert_close(recomputed["next", "shift_distance"], stored)


def test_custom_keys_and_shape_mismatch_error():
    transform = ShiftDistance(observation_key="obs", prediction_key="pred", shift_key="d")
    td = TensorDict(
        pred=torch.zeros(3, 2),
        next=TensorDict(obs=torch.ones(3, 2), batch_size=[3]),
        batch_size=[3],
    )
    torch.testing.assert_close(transform(td)["next", "d"], torch.full((3, 1), 2**0.5))
    td["pred"] = torch.zeros(3, 5)
    with pytest.raises(ValueError, match=r"'pred' has shape \(3, 5\).*'obs' has shape \(3, 2\)"):
        transform(td)
