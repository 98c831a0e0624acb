"""``LaplaceEnsembleActor``'s options, error texts, ``get_dist`` and a multi-step planner
whose read-out needs the trunk's context (``modules/laplace/laplace_ensemble_actor.py``)."""

from __future__ import annotations

import re

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import ENSEMBLE_ACTION_DIM as ACT
from toy import ENSEMBLE_OBS_DIM as OBS
from toy import ensemble_actor as _actor
from toy import ensemble_observation_td as _obs_td
from toy import ensemble_training_data as _training_data
from toy import fitted_ensemble as _fitted_policy
from toy import previous_step_td

from torchrl_dual.diffusion import TrajectoryLayout
from torchrl_dual.modules import LaplaceEnsembleActor, PlannerActor, TransitionModel


def _exact(message: str) -> str:
    return "^" + re.escape(message) + "$"


def _multi_step_planner(make_model) -> PlannerActor:
    """A 4-step planner: its read-out adds the context ``α_t·z_t`` from :meth:`encode`."""
    data = _training_data()
    model = make_model(TrajectoryLayout(OBS, ACT, 4), num_steps=4, fit=False)
    model.normalizer.fit(data["observation"], data["action"] * 2.0)
    return PlannerActor(model)


def test_documented_defaults_and_the_posterior_options_reach_the_laplace(make_model):
    actor = _actor("linear_head", make_model)
    policy = LaplaceEnsembleActor(actor)
    assert policy.num_samples == 5  # paper, Appendix A
    assert policy.laplace.prior_precision_config == "evidence"
    assert policy.laplace.temperature == 1.0
    assert policy.resample_each_call is False and policy.sample_action is True
    assert policy.weight_deviation.shape == (5, ACT, actor.head.in_features)
    other = LaplaceEnsembleActor(
        actor, prior_precision=0.5, posterior_temperature="data", resample_each_call=True
    )
    assert other.laplace.prior_precision_config == 0.5
    assert other.laplace.temperature == "data"
    assert other.resample_each_call is True


def test_resample_each_call_given_at_construction_draws_new_members_per_call(make_model):
    policy = _fitted_policy("linear_head", make_model, resample_each_call=True)
    observation = _obs_td(5)["observation"]
    with torch.no_grad():
        first, second = policy.member_actions(observation), policy.member_actions(observation)
    assert not torch.allclose(first, second)


def test_construction_errors_name_the_fix(make_model):
    with pytest.raises(
        TypeError,
        match=_exact(
            "LaplaceEnsembleActor needs a LastLayerActor (PlannerActor, LinearHeadActor, "
            "DDPMLastStepActor), got Linear; wrap a TorchRL actor with "
            "LinearHeadActor.from_actor(...)."
        ),
    ):
        LaplaceEnsembleActor(torch.nn.Linear(OBS, ACT))
    actor = _actor("planner", make_model)
    with pytest.raises(
        ValueError,
        match=_exact(
            "transition_model=TransitionModel(actor.model) freezes the actor's own planner "
            "(frozen=True is the default), which would stop its fine-tuning. Share the "
            "weights with TransitionModel(actor.model, frozen=False), or keep a frozen "
            "copy with TransitionModel.frozen_copy(actor.model)."
        ),
    ):
        LaplaceEnsembleActor(actor, transition_model=TransitionModel(actor.model))


def test_an_actor_without_a_planner_takes_a_frozen_transition_model(make_model):
    planner = _actor("planner", make_model).model
    transition = TransitionModel(planner)  # frozen, and no actor.model to collide with
    policy = LaplaceEnsembleActor(_actor("linear_head", make_model), transition_model=transition)
    policy.fit_laplace([_training_data()])
    td = previous_step_td(4, obs_dim=OBS, action_dim=ACT, observation_scale=0.2)
    with torch.no_grad():
        out = policy(td)
        expected = transition.predict(td["previous_observation"], td["previous_action"])
    torch.testing.assert_close(out["expected_observation"], expected)


def test_a_missing_observation_and_a_missing_fit_are_named(make_model):
    policy = LaplaceEnsembleActor(_actor("linear_head", make_model))
    with pytest.raises(KeyError, match=re.escape("LaplaceEnsembleActor reads 'observation'")):
        policy(TensorDict({"obs": torch.zeros(3, OBS)}, [3]))
    with pytest.raises(
        RuntimeError,
        match=_exact(
            "LaplaceEnsembleActor samples from the last-layer posterior: call "
            "fit_laplace(...) on the offline data first."
        ),
    ):
        policy(_obs_td())


@pytest.mark.parametrize(("use_low", "use_high"), [(True, False), (False, True)])
def test_a_single_bound_clamps_the_action_on_its_side_only(make_model, use_low, use_high):
    actor = _actor("linear_head", make_model)
    observation = _obs_td(64, scale=3.0)["observation"]
    with torch.no_grad():
        mean = actor(observation)
    low = mean.quantile(0.25).item() if use_low else None
    high = mean.quantile(0.75).item() if use_high else None
    policy = LaplaceEnsembleActor(actor, action_low=low, action_high=high)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        out = policy(TensorDict({"observation": observation}, [64]))
    torch.testing.assert_close(out["action"], mean.clamp(low, high))
    assert not torch.equal(out["action"], mean)


def test_members_of_a_multi_step_planner_are_its_mean_action_moved_by_the_head_draws(
    make_model,
):
    """Only the last step's head is sampled: member ``m`` is the MAP action minus
    ``σ_t·action_std`` times the head deviation ``φ ΔW_mᵀ + Δb_m`` (the read-out is affine)."""
    actor = _multi_step_planner(make_model)
    policy = LaplaceEnsembleActor(actor, num_samples=3)
    policy.fit_laplace([_training_data()])
    observation = _obs_td(4)["observation"]
    torch.manual_seed(5)
    policy.resample()
    torch.manual_seed(5)
    weight, bias = policy.laplace.weight_samples_split(3)
    theta = policy.laplace.theta_map.float()
    with torch.no_grad():
        members = policy.member_actions(observation)
        features = actor.features(observation)
        deviation = torch.einsum("bd,mad->mba", features, weight - theta[:, :-1])
        deviation = deviation + (bias - theta[:, -1])[:, None]
        expected = actor(observation) - actor.readout_scale() * deviation
    torch.testing.assert_close(members, expected, rtol=1e-4, atol=1e-5)
    assert members.std(0).min() > 0


def test_zero_samples_on_a_multi_step_planner_act_with_its_mean_and_write_the_prediction(
    make_model,
):
    actor = _multi_step_planner(make_model)
    transition = TransitionModel.frozen_copy(actor.model)
    policy = LaplaceEnsembleActor(
        actor, num_samples=0, sample_action=False, transition_model=transition
    )
    td = previous_step_td(4, obs_dim=OBS, action_dim=ACT, observation_scale=0.2)
    with set_exploration_type(ExplorationType.RANDOM), torch.no_grad():
        out = policy(td)
        mean = actor(td["observation"])
        expected = transition.predict(td["previous_observation"], td["previous_action"])
    torch.testing.assert_close(out["loc"], mean, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(out["expected_observation"], expected)


def test_get_dist_is_the_ensemble_normal_and_leaves_the_input_alone(make_model):
    policy = _fitted_policy("linear_head", make_model, num_samples=6)
    td = _obs_td(5)
    torch.manual_seed(3)
    dist = policy.get_dist(td)
    assert set(td.keys()) == {"observation"}  # nothing written to the input
    torch.manual_seed(3)
    out = policy(td.clone())
    torch.testing.assert_close(dist.mean, out["loc"])
    torch.testing.assert_close(dist.stddev, out["scale"])
    torch.testing.assert_close(dist.log_prob(out["action"]), out["action_log_prob"])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        dist = policy.get_dist(td)
    with torch.no_grad():
        torch.testing.assert_close(dist.mean, policy.actor(td["observation"]))
        torch.testing.assert_close(dist.stddev, policy.actor.std.expand(5, ACT))
