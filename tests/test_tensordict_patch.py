"""Tests of ``torchrl_dual/_tensordict_patch.py``: the plain-tensor shortcut in front of
``TensorDict.from_any`` returns what tensordict returns, without its ``sys.path`` scan,
and this file fails once tensordict stops scanning (the workaround can then go)."""

from __future__ import annotations

import importlib.util

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule

from torchrl_dual import _tensordict_patch


@pytest.fixture
def scans(monkeypatch):
    """Counts ``importlib.util.find_spec`` calls (what tensordict's ``from_any`` scans with)."""
    calls = []
    original = importlib.util.find_spec

    def counted(name, *args, **kwargs):
        calls.append(name)
        return original(name, *args, **kwargs)

    monkeypatch.setattr(importlib.util, "find_spec", counted)
    return calls


@pytest.fixture
def unpatched():
    was = _tensordict_patch.installed()
    _tensordict_patch.uninstall()
    yield
    if was:
        _tensordict_patch.install()


def test_tensordict_still_scans_for_pandas_at_every_plain_tensor(unpatched, scans):
    """The reason for the workaround. When this fails, tensordict no longer scans:
    delete ``_tensordict_patch.py`` and its two callers."""
    value = torch.zeros(3)
    assert TensorDict.from_any(value) is value
    assert "pandas" in scans


def test_the_shortcut_returns_the_tensor_itself_without_a_scan(unpatched, scans):
    assert _tensordict_patch.install() and _tensordict_patch.installed()
    value = torch.randn(2, 3)
    assert TensorDict.from_any(value) is value
    assert TensorDictBase.from_any(value) is value
    assert scans == []
    _tensordict_patch.uninstall()
    assert not _tensordict_patch.installed()


@pytest.mark.parametrize(
    "obj",
    [
        {"a": torch.zeros(2, 1)},
        (torch.zeros(2), torch.ones(2)),
        [1.0, 2.0],
        TensorDict(a=torch.zeros(2), batch_size=[2]),
        torch.nn.Parameter(torch.zeros(2)),
    ],
    ids=["dict", "tuple", "list", "tensordict", "parameter"],
)
def test_everything_else_goes_to_tensordict_s_own_from_any(unpatched, obj):
    expected = TensorDict.from_any(obj)
    _tensordict_patch.install()
    got = TensorDict.from_any(obj)
    assert type(got) is type(expected)
    if isinstance(expected, TensorDictBase):
        assert (got == expected).all()
    else:
        torch.testing.assert_close(got, expected)


def test_a_tensordict_module_writes_the_same_outputs_with_the_shortcut(unpatched):
    torch.manual_seed(0)
    module = TensorDictModule(torch.nn.Linear(3, 2), in_keys=["x"], out_keys=["y"])
    data = TensorDict(x=torch.randn(4, 3), batch_size=[4])
    expected = module(data.clone())
    _tensordict_patch.install()
    got = module(data.clone())
    assert got.keys() == expected.keys()
    torch.testing.assert_close(got["y"], expected["y"], rtol=0, atol=0)


def test_install_is_idempotent_and_the_opt_out_keeps_tensordict(unpatched, monkeypatch):
    monkeypatch.setenv(_tensordict_patch.OPT_OUT, "0")
    assert _tensordict_patch.install() is False
    assert not _tensordict_patch.installed()
    monkeypatch.delenv(_tensordict_patch.OPT_OUT)
    assert _tensordict_patch.install() and _tensordict_patch.install()
    _tensordict_patch.uninstall()
    assert TensorDictBase.__dict__["from_any"] is _tensordict_patch._ORIGINAL
