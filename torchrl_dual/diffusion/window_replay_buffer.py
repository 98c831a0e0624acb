"""Sampling ``H``-step windows from a TorchRL replay buffer of transitions."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer


class WindowReplayBuffer:
    """Draws batches of ``H + 1``-step windows that never cross an episode boundary.

    A thin composition of TorchRL pieces: a :class:`~torchrl.data.TensorDictReplayBuffer`
    over a :class:`~torchrl.data.LazyTensorStorage`, sampled by a
    :class:`~torchrl.data.SliceSampler` with ``strict_length=True`` and the
    ``episode`` key, so every window lies inside one episode (episodes shorter
    than ``H + 1`` are never drawn).

    .. note::
        ``SliceSampler`` sets ``("next", "done")`` and ``("next", "truncated")`` on the last
        row of every window, even mid-episode, and writes its own ``index`` entry. The
        windows are meant for the planner losses; do not feed them to value learning.

    Args:
        transitions (TensorDictBase): flat ``[N]`` transitions in episode order,
            holding ``observation``, ``action`` and ``traj_key``.
        horizon (int): ``H``; windows have ``H + 1`` rows.
        batch_size (int): number of windows per :meth:`sample`.

    Keyword Args:
        traj_key (str): episode-id key. Defaults to ``"episode"``.
        device (torch.device): where the storage lives. Defaults to ``"cpu"``.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> data = TensorDict(
        ...     {"observation": torch.randn(40, 3), "action": torch.randn(40, 1),
        ...      "episode": torch.arange(40) // 10}, batch_size=[40])
        >>> windows = WindowReplayBuffer(data, horizon=4, batch_size=8).sample()
        >>> windows.batch_size
        torch.Size([8, 5])
        >>> bool((windows["episode"] == windows["episode"][:, :1]).all())
        True
    """

    def __init__(
        self,
        transitions: TensorDictBase,
        horizon: int,
        batch_size: int,
        *,
        traj_key: str = "episode",
        device: torch.device | str = "cpu",
    ) -> None:
        if traj_key not in transitions.keys():
            raise KeyError(
                f"WindowReplayBuffer needs the episode-id key {traj_key!r} to keep windows "
                f"inside episodes; the transitions hold {sorted(transitions.keys())}."
            )
        if transitions.batch_dims != 1:
            raise ValueError(
                f"transitions must be a flat [N] TensorDict, got batch_size "
                f"{tuple(transitions.batch_size)}."
            )
        self.length = horizon + 1
        episodes = transitions[traj_key]
        _, counts = torch.unique_consecutive(episodes, return_counts=True)
        if int(counts.max()) < self.length:
            raise ValueError(
                f"No episode holds the {self.length} steps a horizon-{horizon} window needs "
                f"(longest: {int(counts.max())}); lower the horizon or collect longer episodes."
            )
        self.batch_size = batch_size
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(transitions.shape[0], device=device),
            sampler=SliceSampler(
                slice_len=self.length, traj_key=traj_key, strict_length=True, cache_values=True
            ),
            batch_size=batch_size * self.length,
        )
        self.buffer.extend(transitions)

    def sample(self) -> TensorDictBase:
        """A ``[batch_size, H + 1]`` TensorDict of windows."""
        flat = self.buffer.sample()
        return flat.reshape(self.batch_size, self.length)

    def __len__(self) -> int:
        return len(self.buffer)
