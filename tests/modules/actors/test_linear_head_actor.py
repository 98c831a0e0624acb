"""Tests of ``LinearHeadActor`` (``torchrl_dual/modules/actors/linear_head_actor.py``): any
network ending in ``nn.Linear`` as a last-layer actor ("IQL + LA")."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import (
    AddStateIndependentNormalScale,
    NormalParamExtractor,
    ProbabilisticTensorDictModule,
    ProbabilisticTensorDictSequential,
    TensorDictModule,
)
from torch import nn
from torch.distributions import Normal
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from torchrl_dual.modules import LinearHeadActor
from torchrl_dual.modules.actors.last_layer_actor import TanhSquash


def test_the_mean_is_the_loc_half_of_a_torchrl_mlp_actor():
    net = nn.Sequential(
        MLP(in_features=3, out_features=4, num_cells=[8, 8]), NormalParamExtractor()
    )
    actor = LinearHeadActor(net[0], 2)
    observation = torch.randn(5, 3)
    loc, _ = net(observation)
    torch.testing.assert_close(actor(observation), loc)
    assert actor.head is net[0][-1]
    assert actor.head_rows.tolist() == [0, 1]
    torch.testing.assert_close(actor.readout_scale(), torch.ones(2))


def test_features_are_the_network_without_its_last_layer():
    mlp = MLP(in_features=3, out_features=2, num_cells=[8])
    actor = LinearHeadActor(mlp, 2)
    observation = torch.randn(4, 3)
    torch.testing.assert_close(
        actor.features(observation), nn.Sequential(*list(mlp)[:-1])(observation)
    )
    torch.testing.assert_close(actor.head(actor.features(observation)), mlp(observation))


def test_networks_not_ending_in_linear_are_rejected():
    with pytest.raises(TypeError, match="last module is nn.Linear, got Tanh"):
        LinearHeadActor(
            MLP(in_features=3, out_features=2, num_cells=[8], activate_last_layer=True), 2
        )
    with pytest.raises(TypeError, match="empty network"):
        LinearHeadActor(nn.Sequential(), 2)
    with pytest.raises(ValueError, match="fewer than action_dim=3"):
        LinearHeadActor(MLP(in_features=3, out_features=2, num_cells=[8]), 3)


# ----------------------------------------------------------------------------- from_actor
def _iql_actor(distribution=TanhNormal, **distribution_kwargs):
    torch.manual_seed(0)
    net = nn.Sequential(
        MLP(in_features=3, out_features=4, num_cells=[16, 16]), NormalParamExtractor()
    )
    module = TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(
        module,
        in_keys=["loc", "scale"],
        distribution_class=distribution,
        distribution_kwargs=distribution_kwargs,
    )


def _deterministic_action(iql_actor, observation):
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        td = iql_actor(TensorDict({"observation": observation}, observation.shape[:1]))
    return td["loc"], td["action"]


def test_from_actor_shares_the_weights_of_a_torchrl_probabilistic_actor():
    iql_actor = _iql_actor()
    actor = LinearHeadActor.from_actor(iql_actor)
    observation = torch.randn(6, 3)
    loc, action = _deterministic_action(iql_actor, observation)
    assert actor.action_dim == 2
    torch.testing.assert_close(actor.head_output(actor.features(observation)), loc)
    torch.testing.assert_close(actor(observation), action)
    with torch.no_grad():  # training the TorchRL actor moves the wrapped one too
        iql_actor.module[0].module[0][-1].bias.add_(1.0)
    loc, action = _deterministic_action(iql_actor, observation)
    torch.testing.assert_close(actor.head_output(actor.features(observation)), loc)
    torch.testing.assert_close(actor(observation), action)


# ----------------------------------------------------------------------------- squash
def test_a_tanh_normal_actor_gets_its_box_squash_and_acts_with_its_deterministic_action():
    low, high = torch.tensor([0.0, -2.0]), torch.tensor([1.0, 4.0])
    iql_actor = _iql_actor(low=low, high=high)
    actor = LinearHeadActor.from_actor(iql_actor)
    assert isinstance(actor.squash, TanhSquash)
    observation = torch.randn(64, 3) * 3
    loc, action = _deterministic_action(iql_actor, observation)
    # by hand: low + (high - low) (tanh(loc) + 1) / 2, TanhNormal's deterministic sample
    expected = low + (high - low) * (torch.tanh(loc) + 1) / 2
    torch.testing.assert_close(actor(observation), expected)
    torch.testing.assert_close(actor(observation), action, atol=1e-5, rtol=0)  # SafeTanh clamp
    assert (actor(observation) >= low).all() and (actor(observation) <= high).all()
    assert "squash.center" in actor.state_dict()  # the box is saved with the actor


def test_without_tanh_normal_or_with_squash_none_the_mean_stays_affine():
    normal = LinearHeadActor.from_actor(_iql_actor(distribution=Normal))
    assert normal.squash is None and "squash.center" not in normal.state_dict()
    plain = LinearHeadActor.from_actor(_iql_actor(), squash=None)
    observation = torch.randn(5, 3)
    loc, _ = _deterministic_action(_iql_actor(), observation)
    torch.testing.assert_close(plain(observation), loc)
    with pytest.raises(ValueError, match="tanh_loc=True squashes loc twice"):
        LinearHeadActor.from_actor(_iql_actor(tanh_loc=True))


def test_gradients_of_the_squashed_mean_are_the_chain_rule_through_tanh():
    actor = LinearHeadActor.from_actor(_iql_actor(low=-1.0, high=3.0))
    observation = torch.randn(7, 3)
    actor(observation).sum().backward()
    features = actor.features(observation).detach()
    pre = actor.head_output(features).detach()
    # d a / d b_j = r (1 - tanh²(u_j)), r = (high - low) / 2 = 2, summed over the batch
    expected_bias = (2.0 * (1 - torch.tanh(pre) ** 2)).sum(0)
    torch.testing.assert_close(actor.head.bias.grad[:2], expected_bias)
    torch.testing.assert_close(actor.head.bias.grad[2:], torch.zeros(2))  # the scale half
    expected_weight = (2.0 * (1 - torch.tanh(pre) ** 2)).T @ features
    torch.testing.assert_close(actor.head.weight.grad[:2], expected_weight)
    assert actor.log_std.grad is None  # σ̄ does not enter the mean


def test_from_actor_unwraps_modules_and_plain_networks_and_rejects_others():
    mlp = MLP(in_features=3, out_features=2, num_cells=[8])
    for wrapped in (mlp, TensorDictModule(mlp, in_keys=["observation"], out_keys=["action"])):
        actor = LinearHeadActor.from_actor(wrapped)
        assert actor.action_dim == 2 and actor.head is mlp[-1]
    with pytest.raises(TypeError, match=r"no final nn.Linear.*Tanh"):
        LinearHeadActor.from_actor(nn.Sequential(nn.Linear(3, 2), nn.Tanh()))


# ----------------------------------------------------------------------------- noise after squash
def _squashed_gaussian_network(low=-1.0, high=1.0):
    """CORL's / d3rlpy's IQL actor: ``N(c + r tanh(W s + b), σ²)``, flat, three modules."""
    torch.manual_seed(0)
    return nn.Sequential(nn.Linear(3, 2), TanhSquash(low, high), AddStateIndependentNormalScale(2))


def test_a_squash_before_a_state_independent_scale_is_kept_with_noise_after_the_squash():
    network = _squashed_gaussian_network(low=0.0, high=4.0)
    linear, squash = network[0], network[1]
    actor = LinearHeadActor.from_actor(network)
    assert actor.action_dim == 2 and actor.head is linear
    assert actor.squash is squash  # shared, not a new box
    assert actor.noise_after_squash is True
    observation = torch.randn(5, 3)
    # by hand: c + r tanh(W s + b), c = 2, r = 2
    expected = 2.0 + 2.0 * torch.tanh(observation @ linear.weight.T + linear.bias)
    torch.testing.assert_close(actor(observation), expected)
    torch.testing.assert_close(actor.features(observation), observation)  # no trunk


def test_noise_after_squash_can_be_overridden_in_from_actor():
    network = _squashed_gaussian_network()
    actor = LinearHeadActor.from_actor(network, noise_after_squash=False)
    assert actor.noise_after_squash is False and actor.squash is network[1]
    other = TanhSquash(-2.0, 2.0)
    assert LinearHeadActor.from_actor(network, squash=other).squash is other


def test_the_module_before_a_state_independent_scale_must_have_a_derivative():
    network = nn.Sequential(nn.Linear(3, 2), nn.Tanh(), AddStateIndependentNormalScale(2))
    with pytest.raises(
        TypeError,
        match=r"^LinearHeadActor\.from_actor: the module before the state-independent scale "
        r"must be a squash with a derivative\(\) \(TanhSquash\), got Tanh\.$",
    ):
        LinearHeadActor.from_actor(network)


def test_a_squash_and_scale_without_a_linear_layer_is_rejected():
    """Two modules (no room for the ``nn.Linear``): the network is reported as it ends."""
    network = nn.Sequential(TanhSquash(), AddStateIndependentNormalScale(2))
    with pytest.raises(
        TypeError, match=r"in Sequential \(its network ends with AddStateIndependentNormalScale\)"
    ):
        LinearHeadActor.from_actor(network)


def test_from_actor_error_names_the_actor_and_its_last_module():
    network = nn.Sequential(nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2), nn.Tanh())
    with pytest.raises(
        TypeError,
        match=r"^LinearHeadActor\.from_actor found no final nn\.Linear in Sequential "
        r"\(its network ends with Tanh\)\.$",
    ):
        LinearHeadActor.from_actor(network)
    with pytest.raises(TypeError, match=r"in Sequential \(its network ends with nothing\)\.$"):
        LinearHeadActor.from_actor(nn.Sequential())


def test_constructor_error_names_the_last_module_or_the_empty_network():
    network = nn.Sequential(nn.Linear(3, 4), nn.ReLU(), nn.Linear(4, 2), nn.Tanh())
    with pytest.raises(TypeError, match=r"whose last module is nn\.Linear, got Tanh\.$"):
        LinearHeadActor(network, 2)
    with pytest.raises(
        TypeError, match=r"whose last module is nn\.Linear, got an empty network\.$"
    ):
        LinearHeadActor(nn.Sequential(), 2)


def test_the_readout_scale_lives_on_the_head_device():
    actor = LinearHeadActor(nn.Sequential(nn.Linear(3, 2, device="meta")), 2)
    scale = actor.readout_scale()
    assert scale.device.type == "meta" and scale.shape == (2,)


def test_a_default_tanh_normal_gets_the_unit_box():
    actor = LinearHeadActor.from_actor(_iql_actor())
    torch.testing.assert_close(actor.squash.center, torch.tensor(0.0))
    torch.testing.assert_close(actor.squash.half_range, torch.tensor(1.0))


def test_the_distribution_is_read_from_the_last_module_of_a_longer_actor():
    """A probabilistic sequential with a module between the network and the distribution:
    the ``TanhNormal``'s box is still found (it is the last module, not the second)."""
    torch.manual_seed(0)
    net = nn.Sequential(MLP(in_features=3, out_features=4, num_cells=[8]), NormalParamExtractor())
    actor = ProbabilisticTensorDictSequential(
        TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"]),
        TensorDictModule(nn.Identity(), in_keys=["loc"], out_keys=["loc"]),
        ProbabilisticTensorDictModule(
            in_keys=["loc", "scale"],
            out_keys=["action"],
            distribution_class=TanhNormal,
            distribution_kwargs={"low": 0.0, "high": 2.0},
        ),
    )
    assert len(actor.module) == 3
    wrapped = LinearHeadActor.from_actor(actor)
    assert wrapped.head is net[0][-1]
    assert isinstance(wrapped.squash, TanhSquash)
    torch.testing.assert_close(wrapped.squash.center, torch.tensor(1.0))
    torch.testing.assert_close(wrapped.squash.half_range, torch.tensor(1.0))


def test_a_tanh_loc_tanh_normal_is_rejected_with_the_fix():
    with pytest.raises(
        ValueError,
        match=r"^LinearHeadActor\.from_actor: a TanhNormal with tanh_loc=True squashes loc "
        r"twice; build the actor with tanh_loc=False \(the default\)\.$",
    ):
        LinearHeadActor.from_actor(_iql_actor(tanh_loc=True))


def test_a_probabilistic_sequential_without_a_distribution_module_gets_no_squash():
    """The last module has no ``distribution_class``: nothing to squash to, the mean stays
    the affine read-out."""
    torch.manual_seed(0)
    mlp = MLP(in_features=3, out_features=2, num_cells=[8])
    actor = ProbabilisticTensorDictSequential(
        TensorDictModule(mlp, in_keys=["observation"], out_keys=["loc"]),
        TensorDictModule(nn.Identity(), in_keys=["loc"], out_keys=["action"]),
    )
    wrapped = LinearHeadActor.from_actor(actor)
    assert wrapped.squash is None and wrapped.head is mlp[-1]
    observation = torch.randn(4, 3)
    torch.testing.assert_close(wrapped(observation), mlp(observation))
