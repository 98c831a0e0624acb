"""Atomic, validated run checkpoints, and :func:`state_differences` between two of them."""

from __future__ import annotations

import os
import random
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

FORMAT_VERSION = 1


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be resumed.

    It is missing, corrupt, of another format, or written by a run with other settings.
    The message says which and what to do.
    """


def rng_state() -> dict[str, Any]:
    """The states of Python's, NumPy's and torch's global generators."""
    return {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": torch.get_rng_state(),
    }


def set_rng_state(state: dict[str, Any]) -> None:
    """Restores what :func:`rng_state` returned."""
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])


class RunCheckpoint:
    """One checkpoint file per run, written atomically and checked on load.

    :meth:`save` writes to a temporary file in the same directory and renames it over
    the previous checkpoint (``os.replace``), so a run killed mid-write leaves the last
    complete checkpoint intact. :meth:`load` checks the file's format and that it was
    written by a run with the same ``fingerprint`` (the settings that must not change
    on resume), and says what to do when either check fails.

    Args:
        path (str or Path): checkpoint file.
        fingerprint (dict): JSON-like settings that a resumed run must share.

    Keyword Args:
        free_keys (sequence of str): top-level fingerprint keys a resumed run may change;
            ignored on both sides when a checkpoint is loaded, so a checkpoint written when
            one of them was still fingerprinted loads too. Defaults to none.

    Examples:
        >>> import tempfile, torch
        >>> ckpt = RunCheckpoint(tempfile.mkdtemp() + "/ckpt.pt", {"env": "umaze"})
        >>> ckpt.save({"step": 3, "weights": torch.ones(2)})
        >>> ckpt.load()["step"]
        3
    """

    def __init__(
        self, path: str | Path, fingerprint: dict[str, Any], *, free_keys: Sequence[str] = ()
    ) -> None:
        self.path = Path(path)
        self.fingerprint = fingerprint
        self.free_keys = frozenset(free_keys)

    def exists(self) -> bool:
        """Whether the checkpoint file exists (a run can resume from it)."""
        return self.path.is_file()

    def save(self, state: dict[str, Any]) -> None:
        """Writes ``state`` with this run's format version and fingerprint, atomically.

        Args:
            state (dict): what the run needs to resume (tensors, state dicts, counters); saved
                with :func:`torch.save`, so it may hold anything that pickles.
        """
        self.path.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "format_version": FORMAT_VERSION,
            "fingerprint": self.fingerprint,
            "state": state,
        }
        tmp = self.path.with_name(self.path.name + ".tmp")
        torch.save(payload, tmp)
        os.replace(tmp, self.path)

    def load(self) -> dict[str, Any]:
        """Reads the checkpoint back after checking its format and fingerprint.

        Returns:
            The ``state`` given to :meth:`save`, its tensors on the CPU.

        Raises:
            CheckpointError: the file is missing, unreadable, of another format, or was written
                with a fingerprint that differs from this run's (outside ``free_keys``); the
                message lists the differing settings and what to do.
        """
        if not self.exists():
            raise CheckpointError(
                f"No checkpoint at {self.path}; run without resume=true to start afresh."
            )
        try:
            payload = torch.load(self.path, map_location="cpu", weights_only=False)
        except Exception as err:  # noqa: BLE001 - any unpickling failure means corruption
            raise CheckpointError(
                f"The checkpoint {self.path} is corrupt or unreadable ({type(err).__name__}: "
                f"{err}). Delete it to start afresh, or point output_dir elsewhere."
            ) from err
        if not isinstance(payload, dict) or payload.get("format_version") != FORMAT_VERSION:
            raise CheckpointError(
                f"{self.path} is not a torchrl-dual checkpoint of format {FORMAT_VERSION}; "
                "delete it or use another output_dir."
            )
        saved, now = (
            {k: v for k, v in fp.items() if k not in self.free_keys}
            for fp in (payload["fingerprint"], self.fingerprint)
        )
        if saved != now:
            diff = [
                f"{key}: checkpoint={old!r} now={new!r}"
                for key, old, new in _differences(saved, now)
            ]
            raise CheckpointError(
                f"The checkpoint {self.path} comes from an incompatible run ("
                + "; ".join(diff)
                + "). Resume with the original settings, or use another output_dir."
            )
        return payload["state"]


_MISSING = "<missing>"


def _differences(saved: Any, now: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """The ``(dotted.key, saved, now)`` leaves where two nested dicts differ."""
    if isinstance(saved, dict) and isinstance(now, dict):
        out = []
        for key in sorted(set(saved) | set(now), key=str):
            out += _differences(saved.get(key, _MISSING), now.get(key, _MISSING), f"{prefix}{key}.")
        return out
    return [] if saved == now else [(prefix.rstrip("."), saved, now)]


def state_differences(a: Any, b: Any, ignore: Sequence[str] = ()) -> list[str]:
    """The dotted paths at which two checkpoint states differ, bitwise.

    Walks nested dicts, lists, tuples and TensorDicts; tensors and NumPy arrays must agree
    in dtype, shape and every element (``NaN`` equals ``NaN`` at the same place), other
    leaves by ``==``. A key in ``ignore`` (e.g. ``stage_seconds``, ``logger``: wall times
    and log paths) is skipped wherever it occurs. Used to check that a resumed run ends
    exactly as an uninterrupted one (``benchmarks/robustness/resume_kill.py``).

    Examples:
        >>> import torch
        >>> a = {"w": torch.zeros(2), "frames": 100, "seconds": 1.0}
        >>> b = {"w": torch.tensor([0.0, 1e-9]), "frames": 100, "seconds": 2.0}
        >>> state_differences(a, b, ignore=["seconds"])
        ['w']
    """
    return _differing_paths(a, b, "", frozenset(ignore))


def _differing_paths(a: Any, b: Any, path: str, ignore: frozenset[str]) -> list[str]:
    if _is_mapping(a) and _is_mapping(b):
        a, b = _as_dict(a), _as_dict(b)
        out = []
        for key in sorted(set(a) | set(b), key=str):
            if str(key) in ignore:
                continue
            sub = f"{path}.{key}" if path else str(key)
            both = key in a and key in b
            out += _differing_paths(a[key], b[key], sub, ignore) if both else [sub]
        return out
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        if len(a) != len(b):
            return [path]
        pairs = enumerate(zip(a, b, strict=True))
        return [d for i, (x, y) in pairs for d in _differing_paths(x, y, f"{path}.{i}", ignore)]
    if isinstance(a, torch.Tensor | np.ndarray) or isinstance(b, torch.Tensor | np.ndarray):
        return [] if _same_array(a, b) else [path]
    return [] if a == b else [path]


def _is_mapping(x: Any) -> bool:
    return isinstance(x, dict) or hasattr(x, "batch_size") and hasattr(x, "items")


def _as_dict(mapping: Any) -> dict:
    """A dict, or a TensorDict's leaves by their nested keys joined with dots."""
    if isinstance(mapping, dict):
        return mapping
    return {
        ".".join(k) if isinstance(k, tuple) else k: v
        for k, v in mapping.items(include_nested=True, leaves_only=True)
    }


def _same_array(a: Any, b: Any) -> bool:
    """Same type, dtype, shape and elements (``NaN`` where the other has ``NaN``)."""
    if type(a) is not type(b) or a.dtype != b.dtype or a.shape != b.shape:
        return False
    if isinstance(a, np.ndarray):
        return bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc"))
    if a.is_floating_point() or a.is_complex():
        return torch.equal(a.isnan(), b.isnan()) and torch.equal(a.nan_to_num(), b.nan_to_num())
    return torch.equal(a, b)
