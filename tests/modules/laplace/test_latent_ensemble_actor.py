"""Tests of ``LatentEnsembleActor`` (``torchrl_dual/modules/laplace/latent_ensemble_actor.py``):
the "Ours w τ^N sampling" ablation, ``M`` planner latents aggregated by Eq. (9)."""

from __future__ import annotations

import re

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import previous_step_td

from torchrl_dual.diffusion import TrajectoryDiffusion
from torchrl_dual.modules import PlannerActor, TransitionModel, make_dual_policy
from torchrl_dual.modules.laplace import LatentEnsembleActor


def _actor(make_model, num_steps: int = 1) -> PlannerActor:
    model = make_model(num_steps=num_steps)
    model.normalizer.fit(torch.randn(256, 3) * 2.0 + 1.0, torch.randn(256, 2) * 0.5 + 0.3)
    return PlannerActor(model)


@pytest.mark.parametrize("num_steps", [1, 4])
def test_the_members_differ_and_loc_and_scale_are_their_eq9_moments(make_model, num_steps):
    actor = _actor(make_model, num_steps)
    policy = LatentEnsembleActor(actor, num_samples=6, sample_action=False)
    observation = torch.randn(5, 3)
    with torch.no_grad():
        torch.manual_seed(3)
        members = policy.member_actions(observation)
        torch.manual_seed(3)
        out = policy(TensorDict(observation=observation, batch_size=[5]))
    assert members.shape == (6, 5, 2)
    assert (members.std(0) > 1e-4).all()  # distinct sub-policies
    mean = members.mean(0)
    spread = ((members - mean) ** 2).mean(0)
    torch.testing.assert_close(out["loc"], mean)
    torch.testing.assert_close(out["epistemic_variance"], spread)
    torch.testing.assert_close(out["scale"] ** 2, spread + actor.std**2)
    torch.testing.assert_close(out["action"], mean)  # ShiftAwareNoise draws next


def test_deterministic_mode_acts_with_the_actor_mean(make_model):
    actor = _actor(make_model)
    policy = LatentEnsembleActor(actor, num_samples=3, action_low=-1.0, action_high=1.0)
    observation = torch.randn(4, 3) * 3.0
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        out = policy(TensorDict(observation=observation, batch_size=[4]))
    torch.testing.assert_close(out["action"], actor(observation).clamp(-1.0, 1.0))
    assert (out["epistemic_variance"] == 0).all()


def test_random_mode_samples_around_the_mean_within_bounds(make_model):
    policy = LatentEnsembleActor(
        _actor(make_model), num_samples=4, action_low=-1.0, action_high=1.0
    )
    with torch.no_grad():
        out = policy(TensorDict(observation=torch.randn(64, 3), batch_size=[64]))
    assert (out["action"].abs() <= 1.0).all()
    assert not torch.equal(out["action"], out["loc"].clamp(-1.0, 1.0))
    assert torch.isfinite(out["action_log_prob"]).all()


def test_make_dual_policy_picks_it_and_writes_the_transition_prediction(make_model):
    actor = _actor(make_model)
    transition = TransitionModel.frozen_copy(actor.model)
    policy = make_dual_policy(
        actor, Bounded(-1.0, 1.0, shape=(2,)), transition_model=transition, uncertainty="latent"
    )
    assert isinstance(policy[0], LatentEnsembleActor)
    td = previous_step_td(6)
    with torch.no_grad():
        out = policy(td)
        expected = transition.predict(td["previous_observation"], td["previous_action"])
    torch.testing.assert_close(out["expected_observation"], expected)
    assert out["shift_distance"].shape == (6, 1) and (out["shift_distance"] > 0).all()
    with pytest.raises(ValueError, match="Unknown uncertainty 'bogus'"):
        make_dual_policy(actor, Bounded(-1.0, 1.0, shape=(2,)), shift_weight=0, uncertainty="bogus")


def test_bad_options_are_rejected(make_model, make_layout):
    with pytest.raises(ValueError, match="must be >= 2"):
        LatentEnsembleActor(_actor(make_model), num_samples=1)
    linear = TrajectoryDiffusion(make_layout(), schedule="linear", num_steps=1, hidden=8, depth=1)
    with pytest.raises(ValueError, match="use the cosine schedule"):
        LatentEnsembleActor(PlannerActor(linear))
    with pytest.raises(TypeError, match="needs a PlannerActor"):
        LatentEnsembleActor(torch.nn.Linear(3, 2))


def _exact(message: str) -> str:
    return "^" + re.escape(message) + "$"


def test_five_latents_by_default_and_two_is_the_smallest_ensemble(make_model):
    actor = _actor(make_model)
    assert LatentEnsembleActor(actor).num_samples == 5  # documented default
    policy = LatentEnsembleActor(actor, num_samples=2)
    with torch.no_grad():
        out = policy(TensorDict(observation=torch.randn(3, 3), batch_size=[3]))
    assert (out["epistemic_variance"] > 0).all()
    with pytest.raises(
        ValueError,
        match=_exact("num_samples (M) must be >= 2 for a spread over latents, got 1."),
    ):
        LatentEnsembleActor(actor, num_samples=1)


def test_construction_errors_name_the_type_at_fault_and_the_fix(make_model, make_layout):
    with pytest.raises(
        TypeError,
        match=_exact(
            "LatentEnsembleActor samples the planner's latent: it needs a PlannerActor, got Linear."
        ),
    ):
        LatentEnsembleActor(torch.nn.Linear(3, 2))
    with pytest.raises(
        TypeError, match=_exact("transition_model must be a TransitionModel, got Linear.")
    ):
        LatentEnsembleActor(_actor(make_model), transition_model=torch.nn.Linear(3, 2))
    linear = TrajectoryDiffusion(make_layout(), schedule="linear", num_steps=1, hidden=8, depth=1)
    prefix = (
        "Latent sampling draws τ^N ~ N(0, I), the planner's prior only when its schedule ends "
        "in pure noise (α_1 = 0); the 'linear' schedule has α_1 = "
    )
    with pytest.raises(
        ValueError, match="^" + re.escape(prefix) + r"\d\.\d\de[-+]\d\d: use the cosine schedule\.$"
    ):
        LatentEnsembleActor(PlannerActor(linear))


def test_keys_with_a_transition_model_are_the_policys_and_the_previous_steps(make_model):
    actor = _actor(make_model)
    policy = LatentEnsembleActor(actor, transition_model=TransitionModel.frozen_copy(actor.model))
    assert policy.in_keys == [
        "observation",
        "previous_observation",
        "previous_action",
        "previous_valid",
    ]
    assert policy.out_keys == [
        "loc",
        "scale",
        "epistemic_variance",
        "action",
        "action_log_prob",
        "expected_observation",
    ]


def test_missing_inputs_are_named_with_the_reader(make_model):
    actor = _actor(make_model)
    policy = LatentEnsembleActor(actor, transition_model=TransitionModel.frozen_copy(actor.model))
    with pytest.raises(KeyError, match=re.escape("LatentEnsembleActor reads 'observation'")):
        policy(TensorDict(obs=torch.randn(2, 3), batch_size=[2]))
    with pytest.raises(
        KeyError, match=re.escape("LatentEnsembleActor reads 'previous_observation'")
    ):
        policy(TensorDict(observation=torch.randn(2, 3), batch_size=[2]))


def test_a_float64_previous_action_is_cast_to_the_observation_dtype(make_model):
    actor = _actor(make_model)
    transition = TransitionModel.frozen_copy(actor.model)
    policy = LatentEnsembleActor(actor, transition_model=transition, sample_action=False)
    td = previous_step_td(4)
    td["previous_action"] = td["previous_action"].double()
    with torch.no_grad():
        out = policy(td)
        expected = transition.predict(
            td["previous_observation"], td["previous_action"].to(torch.float32)
        )
    assert out["expected_observation"].dtype == torch.float32
    torch.testing.assert_close(out["expected_observation"], expected)


@pytest.mark.parametrize(("use_low", "use_high"), [(True, True), (True, False), (False, True)])
def test_each_given_bound_clamps_the_deterministic_action(make_model, use_low, use_high):
    actor = _actor(make_model)
    observation = torch.randn(64, 3, generator=torch.Generator().manual_seed(0)) * 3.0
    with torch.no_grad():
        mean = actor(observation)
    low = mean.quantile(0.25).item() if use_low else None  # both bounds bind somewhere
    high = mean.quantile(0.75).item() if use_high else None
    policy = LatentEnsembleActor(actor, action_low=low, action_high=high)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        out = policy(TensorDict(observation=observation, batch_size=[64]))
    torch.testing.assert_close(out["action"], mean.clamp(low, high))
    assert not torch.equal(out["action"], mean)


def test_the_random_action_is_loc_plus_scale_times_a_standard_normal_draw(make_model):
    actor = _actor(make_model)
    policy = LatentEnsembleActor(actor, num_samples=4)
    observation = torch.randn(5, 3)
    with torch.no_grad():
        torch.manual_seed(7)
        members = policy.member_actions(observation)
        eps = torch.randn(5, 2)  # drawn after the latents
        torch.manual_seed(7)
        out = policy(TensorDict(observation=observation, batch_size=[5]))
    loc = members.mean(0)
    scale = (members.var(0, correction=0) + actor.std**2).sqrt()
    torch.testing.assert_close(out["action"], loc + scale * eps)
