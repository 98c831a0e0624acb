"""Tests of ``LatentEnsembleActor`` (``torchrl_dual/modules/laplace/latent_ensemble_actor.py``):
the "Ours w τ^N sampling" ablation, ``M`` planner latents aggregated by Eq. (9)."""

from __future__ import annotations

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
