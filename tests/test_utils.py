"""Tests of ``torchrl_dual/_utils.py``: the one reader of required tensordict entries and the
one test of a deterministic exploration mode that every module shares."""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual._utils import is_deterministic, read_key


def _td() -> TensorDict:
    return TensorDict(
        observation=torch.zeros(2, 3),
        agent=TensorDict(act=torch.ones(2, 1), batch_size=[2]),
        batch_size=[2],
    )


def test_read_key_returns_the_stored_tensor_for_plain_and_nested_keys():
    td = _td()
    assert read_key(td, "observation", "me") is td["observation"]
    assert read_key(td, ("agent", "act"), "me") is td["agent", "act"]


def test_a_missing_key_names_the_reader_the_key_the_keys_present_and_the_fix():
    with pytest.raises(KeyError) as err:
        read_key(_td(), ("agent", "obs"), "The critic", "Pass observation_key=.")
    message = err.value.args[0]
    assert message == (
        "The critic reads ('agent', 'obs'), which the input lacks; it holds "
        "[\"('agent', 'act')\", 'observation']. Pass observation_key=."
    )


def test_without_a_fix_the_message_ends_with_the_keys_present():
    with pytest.raises(KeyError) as err:
        read_key(TensorDict(a=torch.zeros(1), batch_size=[1]), "b", "me")
    assert err.value.args[0] == "me reads 'b', which the input lacks; it holds ['a']."


@pytest.mark.parametrize(
    "mode, expected",
    [
        (ExplorationType.DETERMINISTIC, True),
        (ExplorationType.MODE, True),
        (ExplorationType.MEDIAN, True),
        (ExplorationType.MEAN, True),
        (ExplorationType.RANDOM, False),
    ],
)
def test_is_deterministic_follows_the_exploration_type(mode, expected):
    with set_exploration_type(mode):
        assert is_deterministic() is expected


def test_an_unset_exploration_type_samples():
    assert is_deterministic() is False
