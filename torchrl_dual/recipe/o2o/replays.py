"""The online phase's replay of ``D_offline ∪ D_online`` (Alg. 1 line 15).

A table by ``replay.name``.

* ``mixed`` (``replay/mixed.yaml``, the default): TorchRL's
  :class:`~torchrl.data.OfflineToOnlineReplayBuffer`; every batch takes
  ``online.offline_fraction`` of its transitions uniformly from ``D_offline`` and the rest
  uniformly from ``D_online``.
  With ``online.offline_fraction=joint`` (``budget=paper``'s IQL and DUAL: CORL's) the two
  are one buffer: every transition of ``D_offline ∪ D_online`` is equally likely
  (:class:`JointReplay`), so the offline share falls as ``D_online`` grows.
* ``balanced`` (``replay/balanced.yaml``): OFF2ON's balanced replay (Lee et al. 2022):
  :class:`~torchrl_dual.data.BalancedReplayBuffer` draws each transition of
  ``D_offline ∪ D_online`` in proportion to a clipped power of the density ratio
  ``w(s, a) = d_online / d_offline``; after every update, one Adam step of
  :class:`~torchrl_dual.objectives.DensityRatioLoss` on a uniform offline and a uniform
  online batch, then the priorities of the update's transitions are recomputed (as the
  authors' code does). ``online.offline_fraction`` is not read.

Both share one surface, :class:`Replay`: ``extend`` / ``sample`` / ``online_buffer`` /
``after_update`` (the balanced replay's ratio step and priority refresh) and a
``state_dict`` for the run's checkpoint (the online transitions are saved by the run).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import torch
from tensordict import TensorDictBase
from torchrl.data import OfflineToOnlineReplayBuffer, RandomSampler, ReplayBuffer

from torchrl_dual.data import BalancedReplayBuffer
from torchrl_dual.objectives import DensityRatioLoss, make_density_ratio_network
from torchrl_dual.objectives.optim import adam

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.run import O2ORun


class Replay:
    """What :class:`~torchrl_dual.recipe.O2ORun` samples its online updates from.

    Args:
        buffer: the replay buffer (``extend``, ``sample``, ``online_buffer``).
    """

    def __init__(self, buffer: OfflineToOnlineReplayBuffer | BalancedReplayBuffer) -> None:
        self.buffer = buffer

    @property
    def online_buffer(self) -> ReplayBuffer:
        """``D_online``."""
        return self.buffer.online_buffer

    def extend(self, transitions: TensorDictBase) -> None:
        """Adds online transitions to ``D_online``."""
        self.buffer.extend(transitions)

    def sample(self) -> TensorDictBase:
        """One ``online.batch_size`` batch of ``D_offline ∪ D_online``."""
        return self.buffer.sample()

    def after_update(self, batch: TensorDictBase) -> dict[str, float]:
        """Called with each update's transitions once the update is done; returns metrics."""
        return {}

    def state_dict(self) -> dict[str, Any]:
        """What the checkpoint keeps beyond the online transitions."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: B027 - nothing to load
        """Restores :meth:`state_dict` (after the online transitions were extended)."""


class JointReplay(Replay):
    """``D_offline ∪ D_online`` as one buffer, CORL's fine-tuning replay.

    Each of the ``B`` transitions of a batch is any stored transition with equal
    probability. Drawn as ``k ~ Binomial(B, N_off / (N_off + N_on))`` uniform offline
    transitions and ``B − k`` uniform online ones, which is the distribution of ``B``
    uniform draws (with replacement) from the union, over TorchRL's
    ``OfflineToOnlineReplayBuffer`` (its own fixed share unused).
    """

    def __init__(self, buffer: OfflineToOnlineReplayBuffer, batch_size: int) -> None:
        super().__init__(buffer)
        self.batch_size = batch_size

    def sample(self) -> TensorDictBase:
        """One batch of ``batch_size`` uniform draws from ``D_offline ∪ D_online``."""
        offline, online = self.buffer.offline_buffer, self.buffer.online_buffer
        share = len(offline) / (len(offline) + len(online))
        size = torch.tensor(float(self.batch_size))
        k = int(torch.binomial(size, torch.tensor(share)))
        parts = [b.sample(n) for b, n in ((offline, k), (online, self.batch_size - k)) if n]
        return parts[0] if len(parts) == 1 else torch.cat(parts, 0)


def make_mixed_replay(run: O2ORun) -> Replay:
    """TorchRL's ``OfflineToOnlineReplayBuffer`` with ``online.offline_fraction``.

    ``replay=joint`` gets a :class:`JointReplay` instead.

    Its offline share is drawn from a buffer over the same storage as
    ``run.offline_buffer`` but without a default batch size: TorchRL 0.14 samples it with
    an explicit ``round(offline_fraction * batch_size)`` and warns (once per buffer, a
    "conflicting batch_sizes" ``UserWarning`` in every run's log) when that differs from
    the buffer's own default.
    """
    settings = run.settings
    offline = run.offline_buffer
    joint = settings.online.offline_fraction == "joint"
    buffer = OfflineToOnlineReplayBuffer(
        ReplayBuffer(storage=offline.storage, sampler=RandomSampler()),
        online_capacity=online_capacity(run),
        offline_fraction=0.5 if joint else settings.online.offline_fraction,
        batch_size=settings.online.batch_size,
    )
    return JointReplay(buffer, settings.online.batch_size) if joint else Replay(buffer)


class BalancedReplay(Replay):
    """OFF2ON's balanced replay with its density-ratio network, loss and optimizer."""

    def __init__(self, run: O2ORun) -> None:
        settings, c = run.settings, run.settings.replay
        network = make_density_ratio_network(
            run.data.obs_dim, run.data.action_dim, num_cells=[c.hidden] * c.depth
        ).to(settings.device)
        self.loss = DensityRatioLoss(network).to(settings.device)
        self.optimizer = adam(self.loss.parameters(), lr=c.lr)
        self.device, self.ratio_batch_size = settings.device, c.ratio_batch_size
        super().__init__(
            BalancedReplayBuffer(
                run.offline_buffer,
                online_capacity=online_capacity(run),
                batch_size=settings.online.batch_size,
                ratio_network=network,
                temperature=c.temperature,
            )
        )

    def after_update(self, batch: TensorDictBase) -> dict[str, float]:
        """One density-ratio step, then refreshes the priorities of ``batch``'s transitions.

        ``p = clip(w^{1/T} / mean_off w^{1/T})`` for the transitions of ``batch``
        (flattened if stacked).
        """
        buffer: BalancedReplayBuffer = self.buffer
        ratio_batch = buffer.ratio_batch(self.ratio_batch_size).to(self.device)
        out = self.loss(ratio_batch)
        self.optimizer.zero_grad(set_to_none=True)
        out["loss_density_ratio"].backward()
        self.optimizer.step()
        priority = buffer.refresh_priorities(batch.reshape(-1), reference=ratio_batch)
        return {
            "loss_density_ratio": out["loss_density_ratio"].item(),
            "ratio_offline": out["ratio_offline"].item(),
            "ratio_online": out["ratio_online"].item(),
            "priority_mean": priority.mean().item(),
        }

    def state_dict(self) -> dict[str, Any]:
        """The priorities, the density-ratio network and its optimizer (checkpointed)."""
        return {
            "priorities": self.buffer.state_dict(),
            "ratio": self.loss.state_dict(),
            "ratio_optimizer": self.optimizer.state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restores what :meth:`state_dict` returned."""
        self.buffer.load_state_dict(state["priorities"])
        self.loss.load_state_dict(state["ratio"])
        self.optimizer.load_state_dict(state["ratio_optimizer"])


def online_capacity(run: O2ORun) -> int:
    """``budget.online_frames`` plus what the learner adds (never overwritten)."""
    return max(run.settings.budget.online_frames + run.learner.extra_online_capacity, 1)
