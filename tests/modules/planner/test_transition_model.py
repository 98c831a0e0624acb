"""Tests of ``TransitionModel`` (``torchrl_dual/modules/planner/transition_model.py``): DUAL's
``p(s'|s, a; θ)``, the one owner of ``ŝ_t`` (Algorithm 1 l. 5 and 12, Eq. 10)."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from toy import previous_step_td as _previous_td
from toy import transition_inputs

from torchrl_dual.modules import PlannerActor, PlannerSampler, TransitionModel


# ----------------------------------------------------------------------------- whose weights
def test_a_frozen_transition_model_owns_freezes_and_saves_its_weights(make_model):
    model = make_model(num_steps=1)
    transition = TransitionModel(model)
    assert transition.model is model and transition.frozen
    assert not any(p.requires_grad for p in model.parameters())
    state = transition.state_dict()
    assert set(state) == {f"model.{key}" for key in model.state_dict()}
    assert {id(p) for p in transition.parameters()} == {id(p) for p in model.parameters()}
    transition.double()  # moved with the module
    assert model.denoiser.head.weight.dtype == torch.float64
    restored = TransitionModel(make_model(num_steps=1, seed=5))
    restored.load_state_dict(state)
    inputs = transition_inputs(4)[1:]
    predicted = transition.predict(*(x.double() for x in inputs))
    torch.testing.assert_close(restored.predict(*inputs), predicted.float())


def test_frozen_copy_owns_a_copy_and_leaves_the_source_trainable(make_model):
    model = make_model(num_steps=1)
    transition = TransitionModel.frozen_copy(model, latent="zero")
    assert transition.model is not model
    assert all(p.requires_grad for p in model.parameters())
    assert not any(p.requires_grad for p in transition.parameters())
    inputs = transition_inputs(4)[1:]
    before = transition.predict(*inputs)
    with torch.no_grad():  # the source trains on: the copy keeps the offline weights
        model.denoiser.head.bias.add_(1.0)
    assert torch.equal(transition.predict(*inputs), before)


def test_a_shared_transition_model_stores_nothing_and_follows_the_actor(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    shared = TransitionModel(actor.model, frozen=False)
    assert shared.state_dict() == {} and list(shared.parameters()) == []
    assert all(p.requires_grad for p in actor.model.parameters())  # not frozen
    inputs = transition_inputs(8)
    before = shared.predict(*inputs[1:]).detach()
    optimizer = torch.optim.Adam(actor.parameters(), lr=0.05)
    optimizer.zero_grad()
    actor(inputs[0]).square().sum().backward()
    optimizer.step()
    after = shared.predict(*inputs[1:])
    assert not torch.allclose(after, before, atol=1e-4)
    torch.testing.assert_close(
        after, PlannerSampler(actor.model).predict_next_observation(*inputs[1:], deterministic=True)
    )


# ----------------------------------------------------------------------------- predictions
def test_predict_equals_the_deterministic_sampler_prediction(make_model):
    model = make_model(num_steps=2)
    _, observation, action = transition_inputs(5)
    expected = PlannerSampler(model).predict_next_observation(
        observation, action, deterministic=True
    )
    with set_exploration_type(ExplorationType.RANDOM):  # the zero latent in every mode
        first = TransitionModel(model, frozen=False).predict(observation, action)
        second = TransitionModel(model, frozen=False).predict(observation, action)
    assert torch.equal(first, expected) and torch.equal(second, expected)


def test_a_sampled_latent_draws_under_random_exploration_only(make_model):
    model = make_model(num_steps=1)
    sampled = TransitionModel(model, frozen=False, latent="sample")
    _, observation, action = transition_inputs(5)
    with set_exploration_type(ExplorationType.RANDOM):
        draws = sampled.predict(observation, action), sampled.predict(observation, action)
    assert not torch.allclose(*draws)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        torch.testing.assert_close(
            sampled.predict(observation, action),
            TransitionModel(model, frozen=False).predict(observation, action),
        )


def test_forward_writes_the_prediction_and_s_t_itself_on_reset_rows(make_model):
    transition = TransitionModel(make_model(num_steps=1))
    valid = torch.tensor([[True], [False], [True], [False], [True], [True]])
    td = _previous_td(valid=valid)
    out = transition(td)
    expected = out["expected_observation"]
    predicted = transition.predict(td["previous_observation"], td["previous_action"])
    assert torch.equal(expected[~valid[:, 0]], td["observation"][~valid[:, 0]])  # d_t = 0
    torch.testing.assert_close(expected[valid[:, 0]], predicted[valid[:, 0]])
    assert not torch.allclose(expected[valid[:, 0]], td["observation"][valid[:, 0]])


def test_custom_keys_are_read_and_written(make_model):
    transition = TransitionModel(
        make_model(num_steps=1),
        observation_key="s",
        previous_observation_key=("prev", "s"),
        previous_action_key=("prev", "a"),
        previous_valid_key=("prev", "ok"),
        out_key="s_hat",
    )
    assert transition.in_keys == ["s", ("prev", "s"), ("prev", "a"), ("prev", "ok")]
    assert transition.out_keys == ["s_hat"]
    td = _previous_td()
    renamed = TensorDict(
        s=td["observation"],
        prev=TensorDict(
            s=td["previous_observation"],
            a=td["previous_action"],
            ok=td["previous_valid"],
            batch_size=[6],
        ),
        batch_size=[6],
    )
    out = transition(renamed)
    torch.testing.assert_close(
        out["s_hat"], transition.predict(td["previous_observation"], td["previous_action"])
    )


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize("missing", ["previous_observation", "previous_action", "previous_valid"])
def test_a_missing_previous_entry_names_the_previous_transition_transform(make_model, missing):
    transition = TransitionModel(make_model(num_steps=1))
    with pytest.raises(
        KeyError, match=rf"TransitionModel reads '{missing}'.*Append .*PreviousTransition\(\)"
    ):
        transition(_previous_td().exclude(missing))


def test_bad_models_options_and_shapes_are_rejected(make_model):
    with pytest.raises(TypeError, match="TrajectoryDiffusion planner, got Linear"):
        TransitionModel(nn.Linear(3, 3))
    with pytest.raises(ValueError, match="Unknown latent 'mean'"):
        TransitionModel(make_model(num_steps=1), latent="mean")
    transition = TransitionModel(make_model(num_steps=1))
    td = _previous_td()
    td["previous_observation"] = torch.zeros(6, 1, 3)
    td["previous_action"] = torch.zeros(6, 1, 2)
    with pytest.raises(ValueError, match=r"predicted shape \(6, 1, 3\) for observations of shape"):
        transition(td)
