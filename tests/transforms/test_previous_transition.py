"""Tests of ``PreviousTransition`` (``torchrl_dual/transforms/previous_transition.py``) and the
shift signal d_t of DUAL Eq. 10 it feeds: the transform carries (s_{t-1}, a_{t-1}), a transition
model turns them into ŝ_t and ShiftAwareNoise into d_t, on a tiny env whose dynamics change
mid-rollout."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.collectors import Collector
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, SerialEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from torchrl_dual.modules.exploration.shift_aware_noise import ShiftAwareNoise
from torchrl_dual.transforms import PreviousTransition

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


def original_dynamics(observation, previous_observation, previous_action, previous_valid):
    """ŝ_t = s_{t-1} + a_{t-1} (the dynamics before the change); s_t itself after a reset."""
    return torch.where(previous_valid, previous_observation + previous_action, observation)


def make_policy(action_spec, shift_weight: float = WEIGHT) -> TensorDictSequential:
    """A fake actor with fixed loc/scale, a transition model with the ORIGINAL dynamics, then
    Eq. 10 noise."""

    def fake_actor(observation):
        loc = torch.full_like(observation, LOC)
        return loc, torch.full_like(observation, SCALE), loc.clone()

    actor = TensorDictModule(fake_actor, ["observation"], ["loc", "scale", "action"])
    transition = TensorDictModule(
        original_dynamics,
        ["observation", "previous_observation", "previous_action", "previous_valid"],
        ["expected_observation"],
    )
    noise = ShiftAwareNoise(action_spec, shift_weight)
    return TensorDictSequential(actor, transition, noise)


def make_env(batch_size=()) -> TransformedEnv:
    return TransformedEnv(DriftPointEnv(batch_size), PreviousTransition())


def test_specs_declare_previous_entries_and_reset_has_no_previous_step():
    env = make_env((3,))
    spec = env.observation_spec
    assert spec["previous_observation"].shape == (3, 2)
    assert spec["previous_action"].shape == (3, 2)
    assert spec["previous_valid"].shape == (3, 1)
    assert spec["previous_valid"].dtype == torch.bool
    check_env_specs(env)
    td = env.reset()
    assert not td["previous_valid"].any()
    assert (td["previous_observation"] == 0).all() and (td["previous_action"] == 0).all()


def test_rollout_carries_the_executed_action_and_state_of_the_previous_step():
    env = make_env((4,))
    rollout = env.rollout(HORIZON, make_policy(env.action_spec))
    assert not rollout["previous_valid"][:, 0].any()
    assert rollout["previous_valid"][:, 1:].all()
    torch.testing.assert_close(
        rollout["previous_observation"][:, 1:], rollout["observation"][:, :-1]
    )
    # the executed (noisy) action, not the actor's loc
    torch.testing.assert_close(rollout["previous_action"][:, 1:], rollout["action"][:, :-1])
    assert (rollout["action"] != LOC).all()


def test_partial_resets_clear_only_the_envs_that_reset():
    env = TransformedEnv(
        SerialEnv(2, [lambda: DriftPointEnv(horizon=3), lambda: DriftPointEnv(horizon=5)]),
        PreviousTransition(),
    )
    policy = make_policy(env.action_spec)
    rollout = env.rollout(12, policy, break_when_any_done=False)
    valid = rollout["previous_valid"].squeeze(-1)
    first_steps = [[0, 3, 6, 9], [0, 5, 10]]
    for env_index, starts in enumerate(first_steps):
        expected = torch.ones(12, dtype=torch.bool)
        expected[starts] = False
        assert valid[env_index].tolist() == expected.tolist()
    carried = valid.unsqueeze(-1).expand(-1, -1, 2)
    torch.testing.assert_close(
        rollout["previous_action"][:, 1:][carried[:, 1:]],
        rollout["action"][:, :-1][carried[:, 1:]],
    )


def test_distance_jumps_at_dynamics_change_and_action_spread_follows():
    torch.manual_seed(0)
    env = make_env((2000,))
    rollout = env.rollout(HORIZON, make_policy(env.action_spec), break_when_any_done=False)
    d = rollout["shift_distance"].squeeze(-1)  # [envs, time], d_t used for a_t
    # d_t = ‖ŝ_t - s_t‖ with ŝ_t = s_(t-1) + a_(t-1): 0 at reset and while the model is
    # right, ‖drift‖ = 1 once step t - 1 drifted (t > SHIFT_STEP).
    torch.testing.assert_close(d[:, : SHIFT_STEP + 1], torch.zeros(2000, SHIFT_STEP + 1))
    torch.testing.assert_close(
        d[:, SHIFT_STEP + 1 :], torch.ones(2000, HORIZON - SHIFT_STEP - 1), atol=1e-5, rtol=0
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
    assert data["shift_distance"].shape == (4, 2 * HORIZON, 1)
    # The env moved by the stored action: s' = s + a (+ drift after the change).
    drift = torch.zeros(HORIZON, 2)
    drift[SHIFT_STEP:] = torch.tensor(DRIFT)
    drift = drift.repeat(2, 1)
    moved = data["observation"] + data["action"]
    torch.testing.assert_close(data["next", "observation"], moved + drift)
    # d_t is the drift of the previous step, and 0 after each reset.
    d = data["shift_distance"].squeeze(-1)
    assert (d[:, [0, HORIZON]] == 0).all()
    expected = drift.norm(dim=-1).expand(4, -1)
    torch.testing.assert_close(d[:, 1:HORIZON], expected[:, : HORIZON - 1], atol=1e-5, rtol=0)
    torch.testing.assert_close(d[:, HORIZON + 1 :], expected[:, HORIZON:-1], atol=1e-5, rtol=0)


def test_custom_keys_and_missing_key_errors():
    transform = PreviousTransition(
        observation_key="obs", action_key="act", previous_observation_key="prev_obs"
    )
    assert transform.in_keys == ["obs", "act"]
    assert transform.out_keys == ["prev_obs", "previous_action", "previous_valid"]
    env = TransformedEnv(DriftPointEnv((2,)), PreviousTransition(action_key="thrust"))
    with pytest.raises(KeyError, match=r"no action 'thrust'.*Pass action_key="):
        _ = env.observation_spec
    with pytest.raises(RuntimeError, match="append it to an env"):
        PreviousTransition().transform_observation_spec(DriftPointEnv().observation_spec)
