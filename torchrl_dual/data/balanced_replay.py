"""OFF2ON's balanced replay.

Lee et al., "Offline-to-Online Reinforcement Learning via Balanced Replay and Pessimistic
Q-Ensemble", arXiv:2107.00591.

During fine-tuning, every transition of ``D_offline ∪ D_online`` is drawn with probability
proportional to its priority ``p_i``, a clipped and normalised density ratio
``w(s, a) = d_online / d_offline`` (learnt by
:class:`~torchrl_dual.objectives.DensityRatioLoss`), so offline transitions that look
on-policy are replayed more and the others fade out. As in the authors' code
(``shlee94/Off2OnRL``: ``ours.py``, ``prioritized_replay_buffer.py``):

* ``p = w^{1/T} / mean_{D_offline batch}(w^{1/T})``, clipped to ``[10⁻³, 10³]``, with the
  temperature ``T = 5`` and the mean over a uniform offline batch;
* priorities are refreshed lazily, for the transitions of each sampled batch after the
  update (:meth:`BalancedReplayBuffer.refresh_priorities`);
* offline transitions start at ``p = 1``, and each new online transition gets the largest
  priority seen so far (starting at 1), so it is replayed soon.

TorchRL's ``PrioritizedSampler`` would hold these priorities, but it needs TorchRL's C++
segment trees, which this install lacks; the sampler is therefore ``torch.multinomial``
over the priorities (``O(N)`` per batch, deterministic under ``torch.manual_seed``).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torchrl.data import LazyTensorStorage, ReplayBuffer, Storage

PRIORITY_RANGE = (1e-3, 1e3)


class BalancedReplayBuffer:
    """``D_offline ∪ D_online`` sampled in proportion to OFF2ON's density-ratio priorities.

    The same ``extend()`` / ``sample()`` / ``offline_buffer`` / ``online_buffer`` surface
    as TorchRL's :class:`~torchrl.data.OfflineToOnlineReplayBuffer`: ``extend`` adds online
    data only (first in, first out once ``online_capacity`` is reached), ``sample`` returns
    one flat ``[batch_size]`` TensorDict whose ``index_key`` entry holds each transition's
    index (offline ``0 … N_off − 1``, then online), which
    :meth:`refresh_priorities` reads back.

    Args:
        offline_dataset (ReplayBuffer): the offline data, indexable by position
            (e.g. a ``ReplayBuffer`` on a ``LazyTensorStorage``); it is never modified.

    Keyword Args:
        online_storage (Storage, optional): storage of the online buffer. Mutually
            exclusive with ``online_capacity``.
        online_capacity (int, optional): shorthand for a ``LazyTensorStorage`` of this size.
        batch_size (int, optional): default size of :meth:`sample` and :meth:`ratio_batch`.
        ratio_network (TensorDictModuleBase, optional): writes ``ratio_key`` ``w ≥ 0`` from
            a batch; needed by :meth:`refresh_priorities`. Trained elsewhere (by
            :class:`~torchrl_dual.objectives.DensityRatioLoss`).
        temperature (float): ``T``. Defaults to ``5.0``.
        priority_range (tuple of float): clip of the priorities. Defaults to
            :data:`PRIORITY_RANGE`.
        ratio_key (NestedKey): the network's output. Defaults to ``"density_ratio"``.
        index_key (NestedKey): where :meth:`sample` writes indices. Defaults to ``"index"``.
        online_key (NestedKey): the flag :meth:`ratio_batch` writes. Defaults to ``"online"``.
        transform (Callable, optional): applied to each sampled batch.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import LazyTensorStorage, ReplayBuffer
        >>> offline = ReplayBuffer(storage=LazyTensorStorage(4))
        >>> _ = offline.extend(TensorDict(x=torch.zeros(4), batch_size=[4]))
        >>> rb = BalancedReplayBuffer(offline, online_capacity=4, batch_size=1000)
        >>> _ = rb.extend(TensorDict(x=torch.ones(4), batch_size=[4]))
        >>> rb.update_priority(torch.arange(8), torch.tensor([1., 1, 1, 1, 4, 4, 4, 4]))
        >>> _ = torch.manual_seed(0)
        >>> 0.75 < rb.sample()["x"].mean() < 0.85  # online share 16 / 20
        tensor(True)
    """

    def __init__(
        self,
        offline_dataset: ReplayBuffer,
        *,
        online_storage: Storage | None = None,
        online_capacity: int | None = None,
        batch_size: int | None = None,
        ratio_network: TensorDictModuleBase | None = None,
        temperature: float = 5.0,
        priority_range: tuple[float, float] = PRIORITY_RANGE,
        ratio_key: NestedKey = "density_ratio",
        index_key: NestedKey = "index",
        online_key: NestedKey = "online",
        transform=None,
    ) -> None:
        if (online_storage is None) == (online_capacity is None):
            raise ValueError("Provide exactly one of online_storage or online_capacity.")
        if len(offline_dataset) == 0:
            raise ValueError("The offline dataset is empty; balanced replay needs D_offline.")
        if temperature <= 0:
            raise ValueError(f"temperature must be > 0, got {temperature}.")
        low, high = priority_range
        if not 0 < low <= high:
            raise ValueError(f"priority_range must satisfy 0 < low <= high, got {priority_range}.")
        if online_capacity is not None:
            online_storage = LazyTensorStorage(online_capacity)
        self._offline_buffer = offline_dataset
        self._online_buffer = ReplayBuffer(storage=online_storage)
        self.num_offline = len(offline_dataset)
        self.ratio_network = ratio_network
        self.temperature, self.priority_range = temperature, (low, high)
        self.ratio_key, self.index_key, self.online_key = ratio_key, index_key, online_key
        self._batch_size, self._transform = batch_size, transform
        # p_i of the offline part, then of the online storage's slots
        self._priority = torch.ones(self.num_offline + online_storage.max_size)
        self.max_priority = 1.0

    # ------------------------------------------------------------------ data
    def extend(self, data: TensorDictBase) -> torch.Tensor:
        """Adds online transitions, each with the largest priority seen so far.

        Returns their indices in the online buffer.
        """
        index = torch.as_tensor(self._online_buffer.extend(data))
        self._priority[self.num_offline + index] = self.max_priority
        return index

    def _batch_size_or(self, batch_size: int | None) -> int:
        batch_size = self._batch_size if batch_size is None else batch_size
        if batch_size is None:
            raise ValueError("batch_size must be provided either in __init__ or sample().")
        return batch_size

    def gather(self, index: torch.Tensor) -> TensorDictBase:
        """The transitions at ``index`` (offline ``0 … N_off − 1``, then online), in order."""
        offline = index < self.num_offline
        parts = []
        if bool(offline.any()):
            parts.append(self._offline_buffer[index[offline]])
        if not bool(offline.all()):
            parts.append(self._online_buffer[index[~offline] - self.num_offline])
        order = torch.cat([torch.nonzero(offline).squeeze(-1), torch.nonzero(~offline).squeeze(-1)])
        out = torch.cat(parts, 0) if len(parts) > 1 else parts[0]
        out = out[torch.argsort(order)]
        return out

    @property
    def priorities(self) -> torch.Tensor:
        """``p_i`` of the stored transitions (offline, then online), a copy."""
        return self._priority[: len(self)].clone()

    def probabilities(self) -> torch.Tensor:
        """``p_i / Σ_j p_j`` over the stored transitions (offline, then online)."""
        p = self._priority[: len(self)]
        return p / p.sum()

    def sample(self, batch_size: int | None = None) -> TensorDictBase:
        """Draws ``batch_size`` transitions with replacement, ``P(i) ∝ p_i``.

        Their indices are written under ``index_key``.
        """
        batch_size = self._batch_size_or(batch_size)
        index = torch.multinomial(self._priority[: len(self)], batch_size, replacement=True)
        out = self.gather(index)
        out.set(self.index_key, index)
        if self._transform is not None:
            out = self._transform(out)
        return out

    def ratio_batch(self, batch_size: int | None = None) -> TensorDictBase:
        """Draws the density-ratio estimator's batch: uniform offline then online transitions.

        ``batch_size`` of each, flagged by ``online_key``: the input of
        :class:`~torchrl_dual.objectives.DensityRatioLoss`.
        """
        batch_size = self._batch_size_or(batch_size)
        online = len(self._online_buffer)
        if online == 0:
            raise ValueError("ratio_batch needs online data; call extend() first.")
        index = torch.cat(
            [
                torch.randint(0, self.num_offline, (batch_size,)),
                torch.randint(self.num_offline, self.num_offline + online, (batch_size,)),
            ]
        )
        out = self.gather(index)
        out.set(self.online_key, index >= self.num_offline)
        return out

    # ------------------------------------------------------------------ priorities
    def update_priority(self, index: torch.Tensor, priority: torch.Tensor) -> None:
        """Sets the priorities ``p_i`` at ``index`` and raises the running maximum.

        ``p_i`` is clipped to ``priority_range``; ``index`` numbers the offline then
        the online transitions, as in :meth:`sample`.
        """
        device = self._priority.device
        priority = torch.as_tensor(priority, dtype=self._priority.dtype).flatten().to(device)
        priority = priority.clamp(*self.priority_range)
        self._priority[torch.as_tensor(index).flatten().to(device)] = priority
        self.max_priority = max(self.max_priority, float(priority.max()))

    @torch.no_grad()
    def density_ratio(self, batch: TensorDictBase) -> torch.Tensor:
        """``w(s, a)`` of the ratio network on ``batch``, ``[*B]``."""
        if self.ratio_network is None:
            raise ValueError("BalancedReplayBuffer has no ratio_network; pass one to __init__.")
        td = batch.select(*self.ratio_network.in_keys, strict=False)
        return self.ratio_network(td).get(self.ratio_key).reshape(batch.shape)

    @torch.no_grad()
    def refresh_priorities(
        self, batch: TensorDictBase, reference: TensorDictBase | None = None
    ) -> torch.Tensor:
        """Recomputes the priorities of a sampled ``batch`` from the density ratio and returns them.

        ``p = clip(w^{1/T} / mean_ref(w^{1/T}))``; ``reference`` holds the offline
        transitions of the mean (defaults to a fresh uniform offline batch of the
        same size).
        """
        if reference is None:
            index = torch.randint(0, self.num_offline, (batch.shape[0],))
            reference = self.gather(index)
        elif self.online_key in reference.keys():
            reference = reference[~reference.get(self.online_key)]
        exponent = 1.0 / self.temperature
        normaliser = self.density_ratio(reference).pow(exponent).mean()
        priority = self.density_ratio(batch).pow(exponent) / (normaliser + 1e-10)
        priority = priority.clamp(*self.priority_range)
        self.update_priority(batch.get(self.index_key), priority)
        return priority

    # ------------------------------------------------------------------ bookkeeping
    def state_dict(self) -> dict:
        """The priorities and their running maximum (the data is checkpointed apart)."""
        return {"priority": self._priority.clone(), "max_priority": self.max_priority}

    def load_state_dict(self, state: dict) -> None:
        """Restores the priorities and their running maximum from :meth:`state_dict`.

        Args:
            state (dict): ``{"priority": Tensor [num_offline + online capacity],
                "max_priority": float}``.

        Raises:
            ValueError: the saved priorities have another shape (offline size or online
                capacity differ).
        """
        if state["priority"].shape != self._priority.shape:
            raise ValueError(
                f"Saved priorities have shape {tuple(state['priority'].shape)}, this buffer "
                f"{tuple(self._priority.shape)}: offline size or online capacity differ."
            )
        self._priority.copy_(state["priority"])
        self.max_priority = float(state["max_priority"])

    @property
    def offline_buffer(self) -> ReplayBuffer:
        """The immutable offline dataset."""
        return self._offline_buffer

    @property
    def online_buffer(self) -> ReplayBuffer:
        """The mutable online replay buffer."""
        return self._online_buffer

    def __len__(self) -> int:
        return self.num_offline + len(self._online_buffer)

    def __repr__(self) -> str:
        p = self.probabilities()
        return (
            f"{type(self).__name__}(offline_size={self.num_offline}, "
            f"online_size={len(self._online_buffer)}, "
            f"online_probability={float(p[self.num_offline :].sum()):.3f}, "
            f"temperature={self.temperature}, batch_size={self._batch_size})"
        )
