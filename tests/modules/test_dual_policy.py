"""Tests of ``make_dual_policy`` (``torchrl_dual/modules/dual_policy.py``): DUAL's acting policy,
the Laplace ensemble (Eq. 9) then the shift-aware noise (Eq. 10), with ``ŝ_t`` from a
``TransitionModel`` answered in the ensemble's pass."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.data import Bounded, Composite
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import fine_tuned, transition_inputs
from toy import previous_step_td as _td

from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    PlannerActor,
    ShiftAwareNoise,
    TransitionModel,
    make_dual_policy,
)

SPEC = Bounded(-1.0, 1.0, shape=(2,))


def _fit(policy):
    gen = torch.Generator().manual_seed(0)
    data = TensorDict(observation=torch.randn(128, 3, generator=gen) * 2 + 1, batch_size=[128])
    policy[0].fit_laplace([data])
    return policy


def _transition(actor, kind):
    if kind == "shared":
        return TransitionModel(actor.model, frozen=False)
    return TransitionModel.frozen_copy(fine_tuned(actor.model))


@pytest.mark.parametrize("kind", ["shared", "frozen-copy"])
def test_the_policy_is_the_ensemble_then_the_noise_wired_to_the_transition_model(make_model, kind):
    actor = PlannerActor(make_model(num_steps=1))
    transition = _transition(actor, kind)
    policy = _fit(make_dual_policy(actor, SPEC, transition_model=transition, shift_weight=0.3))
    assert isinstance(policy, TensorDictSequential) and len(policy) == 2
    ensemble, noise = policy[0], policy[1]
    assert isinstance(ensemble, LaplaceEnsembleActor) and isinstance(noise, ShiftAwareNoise)
    assert ensemble.actor is actor and ensemble.transition_model is transition
    assert not ensemble.sample_action and ensemble.num_samples == 5
    assert float(noise.shift_weight) == pytest.approx(0.3)
    valid = torch.tensor([[True], [False], [True], [True], [True], [False]])
    td = _td(valid=valid)
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        out = policy(td)
    predicted = transition.predict(td["previous_observation"], td["previous_action"])
    distance = (predicted - td["observation"]).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(out["shift_distance"], torch.where(valid, distance, 0.0))
    std = (out["scale"] ** 2 + 0.3 * out["shift_distance"]).sqrt()
    torch.testing.assert_close(out["exploration_scale"], std)
    assert out["action"].abs().max() <= 1.0 and not torch.equal(out["action"], out["loc"])


def test_a_positive_shift_weight_without_a_transition_model_is_rejected(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    with pytest.raises(
        ValueError, match=r"shift_weight=0.5 needs ŝ_t.*TransitionModel.frozen_copy"
    ):
        make_dual_policy(actor, SPEC)


def test_a_zero_shift_weight_needs_no_transition_model(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    policy = _fit(make_dual_policy(actor, SPEC, shift_weight=0.0, return_log_prob=True))
    assert policy[0].transition_model is None
    td = TensorDict(observation=transition_inputs(4)[0], batch_size=[4])
    with set_exploration_type(ExplorationType.RANDOM):
        out = policy(td)
    assert (out["shift_distance"] == 0).all()  # d_t unused with λ = 0, written as 0
    torch.testing.assert_close(out["exploration_scale"], out["scale"])
    dist = torch.distributions.Normal(out["loc"], out["scale"])
    clamped = out["action"].abs() == 1.0  # the density is of the projected action
    log_prob = dist.log_prob(out["action"]).sum(-1)
    torch.testing.assert_close(out["action_log_prob"][~clamped.any(-1)], log_prob[~clamped.any(-1)])


def test_deterministic_exploration_gives_the_map_mean_clamped_to_the_spec(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    tight = Bounded(torch.tensor([-0.05, -1.0]), torch.tensor([0.05, 1.0]), shape=(2,))
    policy = _fit(make_dual_policy(actor, tight, transition_model=_transition(actor, "shared")))
    td = _td()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        first, second = policy(td.clone()), policy(td.clone())
    mean = actor(td["observation"])
    assert (mean[:, 0].abs() > 0.05).any()  # the clamp matters
    expected = mean.clamp(tight.space.low, tight.space.high)
    torch.testing.assert_close(first["action"], expected)
    assert torch.equal(first["action"], second["action"])
    assert (first["shift_distance"] == 0).all()


def test_the_ensemble_state_holds_a_frozen_transition_model_once_and_a_shared_one_never(
    make_model,
):
    actor = PlannerActor(make_model(num_steps=1))
    frozen = _transition(actor, "frozen-copy")
    state = make_dual_policy(actor, SPEC, transition_model=frozen).state_dict()
    frozen_keys = [key for key in state if key.startswith("module.0.transition_model.")]
    assert sorted(frozen_keys) == sorted(
        f"module.0.transition_model.model.{key}" for key in frozen.model.state_dict()
    )
    frozen_ptrs = {t.data_ptr() for t in frozen.model.state_dict().values()}
    tensors = {k: v for k, v in state.items() if isinstance(v, torch.Tensor)}
    holders = [k for k, v in tensors.items() if v.data_ptr() in frozen_ptrs]
    assert sorted(holders) == sorted(frozen_keys)  # stored once, under the transition model

    shared = make_dual_policy(
        actor, SPEC, transition_model=_transition(actor, "shared")
    ).state_dict()
    assert not any(key.startswith("module.0.transition_model.") for key in shared)
    assert set(shared) == set(make_dual_policy(actor, SPEC, shift_weight=0.0).state_dict())


def test_the_state_dict_round_trips_into_a_fresh_policy(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    policy = _fit(make_dual_policy(actor, SPEC, transition_model=_transition(actor, "frozen-copy")))
    other = PlannerActor(make_model(num_steps=1, seed=9))
    restored = make_dual_policy(
        other, SPEC, transition_model=TransitionModel.frozen_copy(other.model)
    )
    restored.load_state_dict(policy.state_dict())
    outputs = []
    for module in (policy, restored):
        torch.manual_seed(5)
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            outputs.append(module(_td()))
    for key in ("action", "loc", "scale", "shift_distance", "expected_observation"):
        assert torch.equal(outputs[0][key], outputs[1][key]), key


def test_an_action_projection_is_applied_to_the_executed_action(make_model):
    actor = PlannerActor(make_model(num_steps=1))

    def one_hot(action):
        return torch.nn.functional.one_hot(action.argmax(-1), action.shape[-1]).to(action.dtype)

    policy = _fit(make_dual_policy(actor, SPEC, shift_weight=0.0, action_projection=one_hot))
    out = policy(TensorDict(observation=transition_inputs(8)[0], batch_size=[8]))
    assert torch.equal(out["action"].sum(-1), torch.ones(8))


def test_a_composite_action_spec_is_read_at_its_action_entry(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    spec = Composite(other=Bounded(-5.0, 5.0, shape=(2,)), action=Bounded(-0.1, 0.1, shape=(2,)))
    policy = _fit(make_dual_policy(actor, spec, shift_weight=0.0))
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = policy(TensorDict(observation=transition_inputs(8)[0], batch_size=[8]))
    assert out["action"].abs().max() <= 0.1
