"""Disk cache: round trip, regeneration on mismatch, atomic writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from torchrl_dual.data import (
    OfflineDataset,
    load_cached_dataset,
    load_or_generate,
    make_transitions,
    save_cached_dataset,
)
from torchrl_dual.data import cache as cache_module


def _dataset(n: int = 6, value: float = 1.0) -> OfflineDataset:
    obs = np.full((n, 2), value)
    return OfflineDataset(
        make_transitions(
            obs,
            np.zeros((n, 1)),
            obs,
            np.arange(n),
            np.zeros(n, bool),
            np.ones(n, bool),
            np.arange(n),
        ),
        reference_min=-1.0,
        reference_max=2.0,
        metadata={"source": "test", "value": value},
    )


class Counter:
    def __init__(self, value: float = 1.0):
        self.calls = 0
        self.value = value

    def __call__(self) -> OfflineDataset:
        self.calls += 1
        return _dataset(value=self.value)


def test_cache_round_trip_keeps_transitions_references_and_metadata(tmp_path):
    make = Counter()
    first = load_or_generate(tmp_path / "entry", {"seed": 0}, make)
    second = load_or_generate(tmp_path / "entry", {"seed": 0}, make)
    assert make.calls == 1
    assert (first.transitions == _dataset().transitions).all()
    assert (second.transitions == first.transitions).all()
    assert (second.reference_min, second.reference_max) == (-1.0, 2.0)
    assert second.metadata == {"source": "test", "value": 1.0}


def test_cache_with_mismatched_metadata_is_regenerated(tmp_path):
    load_or_generate(tmp_path / "entry", {"seed": 0, "version": 1}, Counter(1.0))
    make = Counter(5.0)
    data = load_or_generate(tmp_path / "entry", {"seed": 0, "version": 2}, make)
    assert make.calls == 1
    assert data.transitions["observation"].eq(5.0).all()
    assert json.loads((tmp_path / "entry" / "meta.json").read_text())["spec"]["version"] == 2
    assert [p.name for p in tmp_path.iterdir()] == ["entry"]  # old entry removed


def test_interrupted_write_leaves_no_loadable_cache_and_no_leftovers(tmp_path, monkeypatch):
    def interrupted_dump(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(cache_module.json, "dump", interrupted_dump)
    with pytest.raises(KeyboardInterrupt):
        load_or_generate(tmp_path / "entry", {"seed": 0}, Counter())
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []
    assert load_cached_dataset(tmp_path / "entry", {"seed": 0}) is None
    make = Counter()
    load_or_generate(tmp_path / "entry", {"seed": 0}, make)
    assert make.calls == 1


def test_interrupted_generation_keeps_the_previous_entry_intact(tmp_path):
    load_or_generate(tmp_path / "entry", {"seed": 0}, Counter(1.0))

    def failing() -> OfflineDataset:
        raise RuntimeError("generator crashed")

    with pytest.raises(RuntimeError, match="crashed"):
        load_or_generate(tmp_path / "entry", {"seed": 1}, failing)
    assert load_cached_dataset(tmp_path / "entry", {"seed": 0}) is not None


def test_a_killed_writer_leftover_is_never_loaded(tmp_path):
    save_cached_dataset(tmp_path / "entry", {"seed": 0}, _dataset())
    # a hard kill between writing and renaming leaves only the hidden temporary directory
    (tmp_path / "entry").rename(tmp_path / ".entry.tmp-dead")
    assert load_cached_dataset(tmp_path / "entry", {"seed": 0}) is None


def test_entry_without_completion_mark_or_with_bad_json_is_regenerated(tmp_path):
    path = tmp_path / "entry"
    save_cached_dataset(path, {"seed": 0}, _dataset())
    meta = json.loads((path / "meta.json").read_text())
    meta["complete"] = False
    (path / "meta.json").write_text(json.dumps(meta))
    assert load_cached_dataset(path, {"seed": 0}) is None
    (path / "meta.json").write_text("{not json")
    make = Counter()
    load_or_generate(path, {"seed": 0}, make)
    assert make.calls == 1


def test_editing_loaded_transitions_does_not_change_the_cache(tmp_path):
    path = tmp_path / "entry"
    data = load_or_generate(path, {"seed": 0}, Counter())
    data.transitions["observation"].add_(100.0)
    again = load_cached_dataset(path, {"seed": 0})
    assert torch.equal(again.transitions["observation"], torch.ones(6, 2))
    assert isinstance(Path(path), Path)
