"""Tests for the last-layer actors (``μ(s)`` affine in a final ``nn.Linear``, Eq. 5 and Eq. 7)."""

from __future__ import annotations

import copy

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor
from torch import nn
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP

from torchrl_dual.modules import LinearHeadActor, PlannerActor, PlannerPolicy, PlannerSampler


def _with_head(actor, weight: torch.Tensor, bias: torch.Tensor):
    actor = copy.deepcopy(actor)
    with torch.no_grad():
        actor.head.weight.copy_(weight)
        actor.head.bias.copy_(bias)
    return actor


# ----------------------------------------------------------------------------- PlannerActor
def test_planner_actor_equals_the_deterministic_one_step_planner_policy(make_model):
    model = make_model(num_steps=1)
    actor = PlannerActor(model)
    observation = torch.randn(6, 3) * 3.0 + 1.5
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        sampler_action, _ = PlannerSampler(model)(observation)
        policy_td = PlannerPolicy(model)(TensorDict({"observation": observation}, [6]))
    mu = actor(observation)
    assert mu.shape == (6, 2)
    torch.testing.assert_close(mu, sampler_action, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(mu, policy_td["action"], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("batch", [(), (5,), (2, 3)], ids=["unbatched", "B", "B0xB1"])
@pytest.mark.parametrize("latent", ["zero", "sample"])
def test_shared_pass_answers_the_policy_and_the_transition_query(make_model, batch, latent):
    from torchrl_dual.modules import TransitionModel

    model = make_model(num_steps=1)
    actor = PlannerActor(model, latent=latent)
    gen = torch.Generator().manual_seed(0)
    observation = torch.randn(*batch, 3, generator=gen) * 2.0
    previous_observation = torch.randn(*batch, 3, generator=gen)
    previous_action = torch.randn(*batch, 2, generator=gen)
    calls = []
    original = model.denoiser.trunk
    model.denoiser.trunk = lambda hidden: calls.append(hidden.shape) or original(hidden)
    with torch.no_grad():
        torch.manual_seed(1)
        features, context, predicted = actor.encode_with_transition(
            observation, previous_observation, previous_action
        )
        assert len(calls) == 1  # one trunk pass for both queries
        torch.manual_seed(1)
        with torch.enable_grad():  # the general (unfolded) path
            alone = actor.features(observation).detach()
        reference = TransitionModel(model).predict(previous_observation, previous_action)
    assert features.shape == (*batch, model.denoiser.feature_dim)
    assert predicted.shape == observation.shape
    torch.testing.assert_close(features, alone, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(predicted, reference, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(context, observation)


def test_shared_pass_rejects_mismatched_previous_observation(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    with pytest.raises(ValueError, match=r"previous_observation \(4, 3\).*\(5, 3\)"):
        actor.encode_with_transition(torch.zeros(5, 3), torch.zeros(4, 3), torch.zeros(4, 2))


def test_planner_actor_mean_is_affine_in_the_head_weights(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(5, 3)
    gen = torch.Generator().manual_seed(3)
    w1, w2 = (torch.randn(actor.head.weight.shape, generator=gen) * 0.1 for _ in range(2))
    b1, b2 = (torch.randn(actor.head.bias.shape, generator=gen) * 0.1 for _ in range(2))
    with torch.no_grad():
        mu1 = _with_head(actor, w1, b1)(observation)
        mu2 = _with_head(actor, w2, b2)(observation)
        mu_mid = _with_head(actor, (w1 + w2) / 2, (b1 + b2) / 2)(observation)
        mu_ext = _with_head(actor, 2 * w1 - w2, 2 * b1 - b2)(observation)
    assert not torch.allclose(mu1, mu2)
    torch.testing.assert_close(mu_mid, (mu1 + mu2) / 2, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(mu_ext, 2 * mu1 - mu2, rtol=1e-5, atol=1e-5)


def test_planner_actor_readout_scale_is_the_derivative_of_the_action(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(4, 3)
    features = actor.features(observation)
    head = actor.head_output(features)
    delta = 0.5
    shifted = actor.readout(head + delta, observation) - actor.readout(head, observation)
    torch.testing.assert_close(shifted.abs() / delta, actor.readout_scale().expand(4, 2))


def test_planner_actor_features_feed_the_head_that_gives_the_mean(make_model):
    actor = PlannerActor(make_model(num_steps=1))
    observation = torch.randn(4, 3)
    features = actor.features(observation)
    assert features.shape == (4, actor.head.in_features)
    torch.testing.assert_close(
        actor.readout(actor.head_output(features), observation), actor(observation)
    )


def test_planner_actor_rejects_a_multi_step_model_and_bad_options(make_model):
    with pytest.raises(ValueError, match="one-step planner, got num_steps=4"):
        PlannerActor(make_model(num_steps=4))
    with pytest.raises(ValueError, match="choose one of"):
        PlannerActor(make_model(num_steps=1), latent="mean")
    with pytest.raises(ValueError, match="init_std"):
        PlannerActor(make_model(num_steps=1), init_std=5.0)
    with pytest.raises(ValueError, match="observation must end with dim 3"):
        PlannerActor(make_model(num_steps=1))(torch.randn(2, 4))


# ----------------------------------------------------------------------------- LinearHeadActor
def test_linear_head_actor_mean_is_the_loc_half_of_a_torchrl_mlp_actor():
    net = nn.Sequential(
        MLP(in_features=3, out_features=4, num_cells=[8, 8]), NormalParamExtractor()
    )
    actor = LinearHeadActor(net[0], 2)
    observation = torch.randn(5, 3)
    loc, _ = net(observation)
    torch.testing.assert_close(actor(observation), loc)
    assert actor.head is net[0][-1]
    torch.testing.assert_close(actor.readout_scale(), torch.ones(2))


def test_linear_head_actor_rejects_networks_not_ending_in_linear():
    with pytest.raises(TypeError, match="last module is nn.Linear, got Tanh"):
        LinearHeadActor(
            MLP(in_features=3, out_features=2, num_cells=[8], activate_last_layer=True), 2
        )
    with pytest.raises(TypeError, match="empty network"):
        LinearHeadActor(nn.Sequential(), 2)
    with pytest.raises(ValueError, match="fewer than action_dim=3"):
        LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 3)


def test_std_is_the_clamped_exp_of_log_std():
    actor = LinearHeadActor(
        MLP(in_features=3, out_features=2, num_cells=[8]), 2, min_std=0.1, max_std=1.0
    )
    with torch.no_grad():
        actor.log_std.copy_(torch.tensor([-10.0, 10.0]))
    torch.testing.assert_close(actor.std, torch.tensor([0.1, 1.0]))


# ----------------------------------------------------------------------------- from_actor
def _iql_actor():
    from tensordict.nn import TensorDictModule
    from torchrl.modules import ProbabilisticActor, TanhNormal

    torch.manual_seed(0)
    net = nn.Sequential(
        MLP(in_features=3, out_features=4, num_cells=[16, 16]), NormalParamExtractor()
    )
    module = TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(module, in_keys=["loc", "scale"], distribution_class=TanhNormal)


def test_from_actor_shares_the_weights_of_a_torchrl_probabilistic_actor():
    iql_actor = _iql_actor()
    actor = LinearHeadActor.from_actor(iql_actor)
    observation = torch.randn(6, 3)
    td = iql_actor(TensorDict({"observation": observation}, [6]))
    assert actor.action_dim == 2
    torch.testing.assert_close(actor(observation), td["loc"])
    with torch.no_grad():  # training the TorchRL actor moves the wrapped one too
        iql_actor.module[0].module[0][-1].bias.add_(1.0)
    td = iql_actor(TensorDict({"observation": observation}, [6]))
    torch.testing.assert_close(actor(observation), td["loc"])


def test_from_actor_unwraps_modules_and_plain_networks_and_rejects_others():
    from tensordict.nn import TensorDictModule

    mlp = MLP(in_features=3, out_features=2, num_cells=[8])
    for wrapped in (mlp, TensorDictModule(mlp, in_keys=["observation"], out_keys=["action"])):
        actor = LinearHeadActor.from_actor(wrapped)
        assert actor.action_dim == 2 and actor.head is mlp[-1]
    with pytest.raises(TypeError, match=r"no final nn.Linear.*Tanh"):
        LinearHeadActor.from_actor(nn.Sequential(nn.Linear(3, 2), nn.Tanh()))
