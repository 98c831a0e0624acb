"""Tests of ``LinearHeadActor`` (``torchrl_dual/modules/actors/linear_head_actor.py``): any
network ending in ``nn.Linear`` as a last-layer actor ("IQL + LA")."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal

from torchrl_dual.modules import LinearHeadActor


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
def _iql_actor():
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
    mlp = MLP(in_features=3, out_features=2, num_cells=[8])
    for wrapped in (mlp, TensorDictModule(mlp, in_keys=["observation"], out_keys=["action"])):
        actor = LinearHeadActor.from_actor(wrapped)
        assert actor.action_dim == 2 and actor.head is mlp[-1]
    with pytest.raises(TypeError, match=r"no final nn.Linear.*Tanh"):
        LinearHeadActor.from_actor(nn.Sequential(nn.Linear(3, 2), nn.Tanh()))
