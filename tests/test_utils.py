"""Tests of ``torchrl_dual/_utils.py``: the one reader of required tensordict entries, the
action path's writer, and the one test of a deterministic exploration mode that every
module shares."""

from __future__ import annotations

import pytest
import torch
from tensordict import LazyStackedTensorDict, TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_dual._utils import is_deterministic, read_key, write_key


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


def test_read_key_finds_a_nested_tensordict_and_misses_in_a_lazy_stack_alike():
    td = _td()
    assert read_key(td, "agent", "me") is td["agent"]
    stacked = LazyStackedTensorDict.lazy_stack([td, td.clone()])
    assert read_key(stacked, "observation", "me").shape == (2, 2, 3)
    with pytest.raises(KeyError, match="which the input lacks"):
        read_key(stacked, "missing", "me")


def _written(td, key, value):
    """The tensordict after ``write_key``, next to one after ``set`` (the reference)."""
    reference = td.clone()
    reference.set(key, value)
    write_key(td, key, value)
    return td, reference


@pytest.mark.parametrize(
    "make",
    [
        lambda: TensorDict(observation=torch.zeros(2, 3), batch_size=[2]),
        lambda: TensorDict(observation=torch.zeros(2, 3), batch_size=[2], device="cpu"),
        lambda: LazyStackedTensorDict.lazy_stack(
            [TensorDict(observation=torch.zeros(3), batch_size=[]) for _ in range(2)]
        ),
    ],
    ids=["plain", "with_device", "lazy_stack"],
)
@pytest.mark.parametrize("key", ["loc", ("agent", "loc")])
def test_write_key_stores_what_set_stores(make, key):
    value = torch.randn(2, 4)
    td, reference = _written(make(), key, value)
    assert set(td.keys(True, True)) == set(reference.keys(True, True))
    assert td.batch_size == reference.batch_size
    torch.testing.assert_close(td.get(key), reference.get(key))
    write_key(td, key, value + 1.0)  # an existing entry is replaced, as by set
    torch.testing.assert_close(td.get(key), value + 1.0)


def test_write_key_keeps_set_s_checks_for_a_wrong_batch_or_a_locked_tensordict():
    td = TensorDict(observation=torch.zeros(2, 3), batch_size=[2])
    with pytest.raises(RuntimeError, match="batch dimension mismatch"):
        write_key(td, "loc", torch.zeros(5, 1))
    assert "loc" not in td.keys()
    td.lock_()
    with pytest.raises(RuntimeError, match="locked"):
        write_key(td, "loc", torch.zeros(2, 1))


def test_write_key_of_a_non_tensor_value_goes_through_set():
    td = TensorDict(batch_size=[2])
    write_key(td, "nested", TensorDict(x=torch.zeros(2, 1), batch_size=[2]))
    assert td["nested", "x"].shape == (2, 1)


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
