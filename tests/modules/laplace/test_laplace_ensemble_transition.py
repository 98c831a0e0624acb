"""Tests for the Laplace ensemble with a transition model (``ŝ_t`` of Eq. 10): the
expected observation it writes, its keys and state, and a Pendulum collector run with
shift-aware noise."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import ENSEMBLE_ACTION_DIM as ACT
from toy import ENSEMBLE_OBS_DIM as OBS
from toy import assert_all_close, fine_tuned, previous_step_td
from toy import ensemble_actor as _actor
from toy import ensemble_observation_td as _obs_td
from toy import fitted_ensemble as _fitted_policy

from torchrl_dual.diffusion import TrajectoryLayout
from torchrl_dual.modules import (
    LaplaceEnsembleActor,
    PlannerActor,
    ShiftAwareNoise,
    TransitionModel,
)
from torchrl_dual.transforms import PreviousTransition


# ----------------------------------------------------------------------------- (h) collector
@pytest.mark.parametrize("kind", ["shared", "frozen-copy"])
def test_collects_pendulum_with_shift_aware_noise_and_stores_all_keys(make_model, kind):
    from torchrl.collectors import Collector
    from torchrl.envs import GymEnv, TransformedEnv

    env = TransformedEnv(GymEnv("Pendulum-v1"))
    env.append_transform(PreviousTransition())
    env.set_seed(0)
    torch.manual_seed(0)
    model = make_model(TrajectoryLayout(3, 1, 4), num_steps=1, fit=False)
    observation = env.observation_spec["observation"].rand((256,))
    model.normalizer.fit(observation, env.action_spec.rand((256,)))
    transition = (
        TransitionModel(model, frozen=False)
        if kind == "shared"
        else TransitionModel(fine_tuned(model, scale=0.1))
    )
    ensemble = LaplaceEnsembleActor(
        PlannerActor(model), num_samples=5, sample_action=False, transition_model=transition
    )
    ensemble.fit_laplace([TensorDict({"observation": observation}, [256])])
    policy = TensorDictSequential(ensemble, ShiftAwareNoise(env.action_spec))
    collector = Collector(
        env, policy, frames_per_batch=50, total_frames=100, auto_register_policy_transforms=False
    )
    try:
        batches = list(collector)
    finally:
        collector.shutdown()
    assert len(batches) == 2
    for data in batches:
        assert data.batch_size == (50,)
        for key in ("action", "loc", "scale", "epistemic_variance", "shift_distance"):
            assert key in data.keys(True, True), key
        assert (data["epistemic_variance"] > 0).all()
        assert data["action"].abs().max() <= 2.0  # projected on the Pendulum action spec
        std = policy[0].actor.std.detach()
        torch.testing.assert_close(data["scale"] ** 2, data["epistemic_variance"] + std**2)
        # d_t = ‖p(s' | s_(t-1), a_(t-1)) − s_t‖ with the executed a_(t-1); 0 after reset
        valid = data["previous_valid"]
        with torch.no_grad():
            predicted = transition.predict(data["previous_observation"], data["previous_action"])
        expected = torch.where(
            valid, (predicted - data["observation"]).norm(dim=-1, keepdim=True), 0
        )
        torch.testing.assert_close(data["shift_distance"], expected, rtol=1e-4, atol=1e-5)
        torch.testing.assert_close(
            data["previous_action"][1:][valid[1:, 0]], data["action"][:-1][valid[1:, 0]]
        )
        assert (data["shift_distance"][valid] > 0).all()
        scale = (data["scale"] ** 2 + 0.5 * data["shift_distance"]).sqrt()
        torch.testing.assert_close(data["exploration_scale"], scale)


# ----------------------------------------------------------------------------- (k) transition
def _previous_td(batch: int = 6, valid=None) -> TensorDict:
    return previous_step_td(batch, valid=valid, obs_dim=OBS, action_dim=ACT, observation_scale=0.2)


@pytest.mark.parametrize("kind", ["shared", "frozen-copy", "linear-head"])
def test_with_a_transition_model_the_ensemble_also_writes_the_expected_observation(
    make_model, kind
):
    if kind == "linear-head":  # any last-layer actor: the generic two calls
        policy = _fitted_policy("linear_head", make_model)
        transition = TransitionModel(_actor("planner", make_model).model)
    else:
        policy = _fitted_policy("planner", make_model)
        model = policy.actor.model
        transition = (
            TransitionModel(model, frozen=False)
            if kind == "shared"
            else TransitionModel.frozen_copy(fine_tuned(model))
        )
    policy.transition_model = transition
    valid = torch.tensor([[True], [False], [True], [True], [False], [True]])
    td = _previous_td(valid=valid)
    torch.manual_seed(2)
    with torch.no_grad():  # the action path: one-pass shortcut for the planner actor
        with_transition = policy(td.clone())
    torch.manual_seed(2)
    policy.transition_model = None
    without = policy(td.clone())  # autograd on: the plain trunk pass
    predicted = transition.predict(td["previous_observation"], td["previous_action"])
    expected = torch.where(valid, predicted, td["observation"])
    torch.testing.assert_close(with_transition["expected_observation"], expected)
    assert "expected_observation" not in without.keys()
    keys = ("loc", "scale", "epistemic_variance", "action", "action_log_prob")
    assert_all_close([with_transition[k] for k in keys], [without[k] for k in keys])


def test_the_transition_model_adds_its_keys_and_is_registered_once(make_model):
    actor = _actor("planner", make_model)
    frozen = TransitionModel.frozen_copy(actor.model)
    policy = LaplaceEnsembleActor(actor, transition_model=frozen)
    assert policy.in_keys == [
        "observation",
        "previous_observation",
        "previous_action",
        "previous_valid",
    ]
    assert policy.out_keys[-1] == "expected_observation"
    state = policy.state_dict()
    frozen_keys = [key for key in state if key.startswith("transition_model.")]
    assert sorted(frozen_keys) == sorted(
        f"transition_model.model.{k}" for k in frozen.model.state_dict()
    )
    shared = LaplaceEnsembleActor(
        actor, transition_model=TransitionModel(actor.model, frozen=False)
    )
    assert not any(key.startswith("transition_model.") for key in shared.state_dict())
    assert set(shared.state_dict()) == set(LaplaceEnsembleActor(actor).state_dict())


def test_deterministic_modes_skip_the_transition_query(make_model):
    policy = _fitted_policy("planner", make_model)
    policy.transition_model = TransitionModel(policy.actor.model, frozen=False)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = policy(_obs_td(4))  # no previous_* entries needed
    torch.testing.assert_close(out["expected_observation"], out["observation"])  # ŝ_t = s_t
    torch.testing.assert_close(out["action"], policy.actor(_obs_td(4)["observation"]))


def test_a_missing_previous_entry_names_the_ensemble_and_the_transform(make_model):
    policy = _fitted_policy("planner", make_model)
    policy.transition_model = TransitionModel(policy.actor.model, frozen=False)
    with pytest.raises(
        KeyError, match=r"LaplaceEnsembleActor reads 'previous_action'.*PreviousTransition"
    ):
        policy(_previous_td().exclude("previous_action"))


def test_a_non_last_layer_actor_or_transition_model_is_rejected(make_model):
    with pytest.raises(TypeError, match=r"needs a LastLayerActor.*got Linear.*from_actor"):
        LaplaceEnsembleActor(nn.Linear(2, 2))
    actor = _actor("planner", make_model)
    with pytest.raises(TypeError, match="transition_model must be a TransitionModel, got function"):
        LaplaceEnsembleActor(actor, transition_model=lambda s, a: s)


def test_a_frozen_transition_model_on_the_actors_own_planner_is_refused(make_model):
    from torchrl_dual.modules import PlannerActor, TransitionModel

    model = make_model(num_steps=1)
    actor = PlannerActor(model)
    with pytest.raises(ValueError, match="frozen=False"):
        LaplaceEnsembleActor(actor, transition_model=TransitionModel(model))
