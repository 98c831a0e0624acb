"""Replay buffers over transition TensorDicts."""

from __future__ import annotations

from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyMemmapStorage, LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import Sampler

from torchrl_dual.data.transition_layout import validate_transitions

_STORAGES = ("tensor", "memmap")


def to_replay_buffer(
    td: TensorDictBase,
    *,
    sampler: Sampler | None = None,
    batch_size: int | None = None,
    storage: str = "tensor",
    max_size: int | None = None,
    scratch_dir: str | Path | None = None,
    device: torch.device | str | None = None,
    validate: bool = True,
) -> TensorDictReplayBuffer:
    """Wraps transitions in a :class:`~torchrl.data.TensorDictReplayBuffer`.

    Args:
        td (TensorDictBase): transitions in the project layout (see
            :mod:`torchrl_dual.data.transition_layout`).

    Keyword Args:
        sampler (Sampler, optional): e.g. :class:`~torchrl.data.SliceSampler` with
            ``traj_key="episode"`` for trajectory windows; defaults to uniform sampling.
        batch_size (int, optional): default sample size.
        storage (str): ``"tensor"`` (:class:`~torchrl.data.LazyTensorStorage`, in RAM) or
            ``"memmap"`` (:class:`~torchrl.data.LazyMemmapStorage`, on disk).
        max_size (int, optional): storage capacity; defaults to ``len(td)`` (raise it to
            leave room for online data).
        scratch_dir (str or Path, optional): directory of the memmap storage.
        device (torch.device or str, optional): storage device.
        validate (bool): run :func:`validate_transitions` first. Defaults to ``True``.

    Examples:
        >>> import numpy as np
        >>> from torchrl.data import SliceSampler
        >>> from torchrl_dual.data import make_transitions
        >>> n = 20
        >>> obs = np.arange(n, dtype=np.float32)[:, None]
        >>> td = make_transitions(obs, np.zeros((n, 1)), obs + 1, np.zeros(n),
        ...     np.zeros(n, bool), np.zeros(n, bool), np.repeat([0, 1], 10))
        >>> rb = to_replay_buffer(td, sampler=SliceSampler(slice_len=4, traj_key="episode"),
        ...     batch_size=8)
        >>> windows = rb.sample()["episode"].reshape(2, 4)
        >>> bool((windows == windows[:, :1]).all())  # a window never crosses episodes
        True
    """
    if storage not in _STORAGES:
        raise ValueError(f"storage must be one of {_STORAGES}, got {storage!r}.")
    if validate:
        validate_transitions(td)
    n = td.batch_size[0]
    capacity = n if max_size is None else int(max_size)
    if capacity < n:
        raise ValueError(f"max_size={capacity} is smaller than the {n} transitions to store.")
    if storage == "memmap":
        store = LazyMemmapStorage(capacity, scratch_dir=scratch_dir, device=device or "cpu")
    else:
        if scratch_dir is not None:
            raise ValueError("scratch_dir is only used with storage='memmap'.")
        store = LazyTensorStorage(capacity, device=device or "cpu")
    kwargs = {} if sampler is None else {"sampler": sampler}
    rb = TensorDictReplayBuffer(storage=store, batch_size=batch_size, **kwargs)
    if n:
        rb.extend(td)
    return rb
