"""Tests of ``RunCheckpoint`` and the RNG helpers (``torchrl_dual/checkpoint.py``): atomic saves,
and loads that refuse a corrupt file, another format or an incompatible run."""

from __future__ import annotations

import pickle
import random

import numpy as np
import pytest
import torch

from torchrl_dual.checkpoint import (
    FORMAT_VERSION,
    CheckpointError,
    RunCheckpoint,
    rng_state,
    set_rng_state,
    state_differences,
)

FINGERPRINT = {"env": {"name": "umaze", "seed": 0}, "lr": 1e-3}


def test_save_then_load_round_trips_the_state(tmp_path):
    ckpt = RunCheckpoint(tmp_path / "deep" / "dir" / "ckpt.pt", FINGERPRINT)
    assert not ckpt.exists()
    ckpt.save({"step": 7, "weights": torch.arange(4.0), "nested": {"a": [1, 2]}})
    assert ckpt.exists()
    state = ckpt.load()
    assert state["step"] == 7 and state["nested"] == {"a": [1, 2]}
    assert torch.equal(state["weights"], torch.arange(4.0))
    ckpt.save({"step": 8})  # a later save replaces the earlier one
    assert ckpt.load() == {"step": 8}
    assert [p.name for p in ckpt.path.parent.iterdir()] == ["ckpt.pt"]  # no leftover temp file


def test_a_failed_write_leaves_the_previous_checkpoint_intact(tmp_path):
    ckpt = RunCheckpoint(tmp_path / "ckpt.pt", FINGERPRINT)
    ckpt.save({"step": 1, "weights": torch.ones(3)})
    before = ckpt.path.read_bytes()
    with pytest.raises((pickle.PicklingError, AttributeError)):  # a local lambda: no pickle
        ckpt.save({"step": 2, "unpicklable": lambda: None})
    assert ckpt.path.read_bytes() == before
    assert ckpt.load()["step"] == 1


def test_a_fingerprint_mismatch_names_every_dotted_key_with_both_values(tmp_path):
    RunCheckpoint(tmp_path / "ckpt.pt", FINGERPRINT).save({"step": 1})
    now = {"env": {"name": "medium", "seed": 0}, "lr": 1e-3, "batch": 64}
    with pytest.raises(CheckpointError) as err:
        RunCheckpoint(tmp_path / "ckpt.pt", now).load()
    message = str(err.value)
    assert "env.name: checkpoint='umaze' now='medium'" in message
    assert "batch: checkpoint='<missing>' now=64" in message
    assert "env.seed" not in message and "lr" not in message.split("(")[1]
    assert "Resume with the original settings, or use another output_dir" in message


def test_free_keys_may_differ_or_be_missing_on_either_side(tmp_path):
    """A checkpoint written while ``collector`` was still fingerprinted loads in a run that
    treats it as free, and a free key may change; the other keys still must match."""
    path = tmp_path / "ckpt.pt"
    RunCheckpoint(path, {"env": "umaze", "collector": {"name": "single"}, "out": "a"}).save({})
    free = ("collector", "out")
    assert RunCheckpoint(path, {"env": "umaze", "out": "b"}, free_keys=free).load() == {}
    with pytest.raises(CheckpointError, match=r"\(env: checkpoint='umaze' now='medium'\)"):
        RunCheckpoint(path, {"env": "medium"}, free_keys=free).load()
    with pytest.raises(CheckpointError, match="collector: checkpoint="):
        RunCheckpoint(path, {"env": "umaze", "out": "a"}).load()  # not free: a difference


def test_a_corrupt_file_is_reported_as_such(tmp_path):
    path = tmp_path / "ckpt.pt"
    path.write_bytes(b"not a checkpoint at all")
    with pytest.raises(CheckpointError, match=r"ckpt.pt is corrupt or unreadable \(.*Delete it"):
        RunCheckpoint(path, FINGERPRINT).load()


@pytest.mark.parametrize(
    "payload",
    [{"format_version": FORMAT_VERSION + 1, "fingerprint": FINGERPRINT, "state": {}}, [1, 2]],
    ids=["newer-format", "not-a-dict"],
)
def test_another_format_is_refused(tmp_path, payload):
    path = tmp_path / "ckpt.pt"
    torch.save(payload, path)
    with pytest.raises(
        RuntimeError, match=rf"not a torchrl-dual checkpoint of format {FORMAT_VERSION}"
    ):
        RunCheckpoint(path, FINGERPRINT).load()


def test_loading_a_missing_checkpoint_says_how_to_start_afresh(tmp_path):
    with pytest.raises(CheckpointError, match="run without resume=true"):
        RunCheckpoint(tmp_path / "none.pt", FINGERPRINT).load()


def _draws():
    return random.random(), float(np.random.rand()), float(torch.rand(()))


def test_the_rng_state_round_trips_through_a_checkpoint(tmp_path):
    ckpt = RunCheckpoint(tmp_path / "ckpt.pt", FINGERPRINT)
    ckpt.save({"rng": rng_state()})
    expected = _draws()
    assert _draws() != expected  # the generators moved on
    set_rng_state(ckpt.load()["rng"])
    assert _draws() == expected


# ----------------------------------------------------------------------------- state_differences
def test_state_differences_finds_every_differing_leaf_by_its_path():
    from tensordict import TensorDict

    a = {
        "net": {"w": torch.zeros(3), "b": torch.ones(1)},
        "history": [{"frames": 100, "score": 1.5}],
        "online_data": TensorDict(
            obs=torch.arange(4.0), next=TensorDict(r=torch.zeros(4), batch_size=[4]), batch_size=[4]
        ),
        "rng": {"numpy": ("MT", np.arange(3))},
        "seconds": 1.0,
    }
    b = {
        "net": {"w": torch.zeros(3), "b": torch.ones(1, dtype=torch.float64)},  # dtype
        "history": [{"frames": 100, "score": 1.25}],  # a value in a list
        "online_data": TensorDict(
            obs=torch.arange(4.0),
            next=TensorDict(r=torch.tensor([0.0, 0, 0, 1e-30]), batch_size=[4]),
            batch_size=[4],
        ),
        "rng": {"numpy": ("MT", np.arange(3))},
        "seconds": 2.0,
        "extra": 0,  # missing on one side
    }
    assert state_differences(a, a) == []
    assert state_differences(a, b, ignore=["seconds"]) == [
        "extra",
        "history.0.score",
        "net.b",
        "online_data.next.r",
    ]
    assert "seconds" in state_differences(a, b)


def test_state_differences_counts_nan_at_the_same_place_as_equal():
    nan = float("nan")
    assert state_differences({"x": torch.tensor([nan, 1.0])}, {"x": torch.tensor([nan, 1.0])}) == []
    assert state_differences({"x": torch.tensor([nan, 1.0])}, {"x": torch.tensor([1.0, nan])}) == [
        "x"
    ]
    assert state_differences({"x": np.array([nan])}, {"x": np.array([nan])}) == []
    assert state_differences({"x": torch.zeros(2)}, {"x": torch.zeros(3)}) == ["x"]
    assert state_differences({"x": [1, 2]}, {"x": [1, 2, 3]}) == ["x"]
    assert state_differences({"x": torch.zeros(1)}, {"x": np.zeros(1)}) == ["x"]
