"""The online phase's collector (Alg. 1 lines 11-12), a table by ``collector.name``.

* ``single`` (``collector/single.yaml``, the default): TorchRL's
  :class:`~torchrl.collectors.Collector` steps the run's online env in this process with the
  learner's exploration policy.
* ``multi_sync`` (``collector/multi_sync.yaml``): TorchRL's
  :class:`~torchrl.collectors.MultiSyncCollector`; ``collector.num_workers`` processes each
  step their own env for ``budget.frames_per_batch / num_workers`` frames, and the run gets
  their batches stacked (``[num_workers, T]``) once all are done.
* ``multi_async`` (``collector/multi_async.yaml``): TorchRL's
  :class:`~torchrl.collectors.MultiAsyncCollector`; each worker keeps collecting and the
  run gets whichever worker's ``budget.frames_per_batch`` frames are ready first.
* ``ray`` (``collector/ray.yaml``, the ``torchrl-dual[ray]`` extra): TorchRL's
  :class:`~torchrl.collectors.distributed.RayCollector`, ``collector.num_workers`` remote
  collectors (Ray actors, possibly on other nodes), batches stacked like ``multi_sync``
  (``collector.sync=true``) or first-come like ``multi_async``; see
  :mod:`torchrl_dual.recipe.o2o.ray_collector`.

Every worker builds its env with :class:`~torchrl_dual.recipe.kits.build.TrainEnvFactory`
(a picklable ``cfg -> env``, so its ``PreviousTransition`` and hence the shift signal
``d_t`` of Eq. (10) follow that worker's own trajectory). The workers act with an *acting copy* of the learner's
exploration policy, whose tensors they share (TorchRL's ``SharedMemWeightSyncScheme``):
the updates never touch it, so an asynchronous worker never reads a network mid-update or a
Laplace posterior mid-refit. The run calls its collector kind's ``push`` after every block
of updates (:func:`push_to_processes`: the current parameters *and buffers*, DUAL's
Laplace posterior draws refitted every ``budget.laplace_refit_every`` updates, copied into
the acting copy); ``multi_sync``'s next batch acts with them, ``multi_async``'s batches in
flight switch over mid-batch. Ray's remote collectors hold their own copies and receive
the same tensors (:func:`~torchrl_dual.recipe.o2o.ray_collector.push_to_actors`).

Episode ids: :func:`assign_episodes` maps TorchRL's ``("collector", "traj_ids")`` (unique
across the workers of one collector; Ray's remote collectors number them apart, see
:class:`~torchrl_dual.recipe.o2o.ray_collector.InterleavedTrajectories`) to the run's episode
ids, so that an episode that spans batches keeps its id and ids are never reused, also
after a resume (a resumed run's collector starts new trajectories, numbered from the
largest stored id + 1).

Cal-QL's Monte-Carlo labels (``critic=calql``) hold one stream of transitions until its
episode ends: :func:`check_collector` refuses them with several workers.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple

import torch
from omegaconf import DictConfig
from tensordict import TensorDict
from torch import nn
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs.utils import ExplorationType

from torchrl_dual.recipe.kits.build import TrainEnvFactory
from torchrl_dual.recipe.o2o.ray_collector import check_ray_collector, make_ray, push_to_actors
from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.rules import Flag, Integer, Maybe, Text, key

if TYPE_CHECKING:
    from torchrl.collectors import BaseCollector

    from torchrl_dual.recipe.o2o.run import O2ORun


@dataclass
class CollectorSettings:
    """``collector/single.yaml``: the name only (one process, the run's own env)."""

    name: str = key(Text(), "the COLLECTORS entry")


@dataclass
class MultiCollectorSettings(CollectorSettings):
    """``collector/multi_sync.yaml`` and ``collector/multi_async.yaml``."""

    num_workers: int = key(Integer(1), "worker processes, each stepping its own env")


@dataclass
class RayCollectorSettings(CollectorSettings):
    """``collector/ray.yaml`` (:mod:`torchrl_dual.recipe.o2o.ray_collector`)."""

    num_workers: int = key(Integer(1), "remote collectors (Ray actors), each stepping an env")
    sync: bool = key(Flag(), "true: batches stacked as multi_sync; false: first come")
    address: Any = key(Maybe(Text()), "the Ray cluster (null: a running one, else local)")


def make_single(run: O2ORun, total_frames: int) -> BaseCollector:
    """TorchRL's ``Collector`` on ``run.env`` (seeded ``seed + 1 + frames``)."""
    cfg = run.cfg
    run.env.set_seed(cfg.seed + 1 + run.frames)
    return Collector(
        run.env,
        run.learner.exploration_policy,
        frames_per_batch=cfg.budget.frames_per_batch,
        total_frames=total_frames,
        exploration_type=ExplorationType.RANDOM,
        device=cfg.device,
        auto_register_policy_transforms=False,
    )


def make_multi(collector_class: type) -> Callable[[O2ORun, int], BaseCollector]:
    """``(run, total_frames) -> collector`` for TorchRL's multi-process ``collector_class``."""

    def make(run: O2ORun, total_frames: int) -> BaseCollector:
        cfg = run.cfg
        collector = collector_class(
            [TrainEnvFactory(cfg, run.data)] * cfg.collector.num_workers,
            copy.deepcopy(run.learner.exploration_policy),  # the acting copy
            frames_per_batch=cfg.budget.frames_per_batch,
            total_frames=total_frames,
            exploration_type=ExplorationType.RANDOM,
            device=cfg.device,
            num_threads=cfg.num_threads,  # this process's threads (TorchRL would lower them)
            auto_register_policy_transforms=False,
        )
        try:  # worker 0 gets seed + 1 + frames, the others TorchRL's chained seeds
            collector.set_seed(cfg.seed + 1 + run.frames)
        except BaseException:
            collector.shutdown()
            raise
        return collector

    return make


def check_worker_count(cfg: DictConfig) -> None:
    """``collector.num_workers`` with ``collector=single`` (run before the key checks, which
    would only call it an unknown key)."""
    if cfg.collector.name == "single" and "num_workers" in cfg.collector:
        raise ConfigError(
            "collector.num_workers",
            cfg.collector.num_workers,
            "collector=single collects in this process; choose collector=multi_sync or "
            "collector=multi_async for worker processes, collector=ray for Ray actors",
        )


def check_collector(cfg: DictConfig) -> None:
    """The combinations of ``collector.*`` with other keys that cannot work."""
    name = cfg.collector.name
    if name == "single":
        return
    if name == "ray":
        check_ray_collector(cfg)
    workers = cfg.collector.num_workers
    stacked = name == "multi_sync" or (name == "ray" and cfg.collector.sync)
    if stacked and cfg.budget.frames_per_batch % workers:  # one slice per worker
        sync = " collector.sync=true" if name == "ray" else ""
        raise ConfigError(
            "budget.frames_per_batch",
            cfg.budget.frames_per_batch,
            f"collector={name}{sync} splits each batch over collector.num_workers={workers}: "
            "use a multiple of it",
        )
    if cfg.critic.name == "calql":
        raise ConfigError(
            "collector",
            name,
            "critic=calql labels one stream of online episodes with Monte-Carlo returns; "
            "use collector=single with it",
        )


def push_nothing(collector: BaseCollector, policy: nn.Module) -> None:
    """``collector=single`` acts with ``policy`` itself: nothing to push."""


def push_to_processes(collector: BaseCollector, policy: nn.Module) -> None:
    """Copies ``policy``'s current parameters and buffers into the collector's acting copy,
    which its worker processes share.

    Raises:
        RuntimeError: a worker process has died (its traceback is printed above); the
            run's ``finally`` then shuts the others down.
    """
    for index, process in enumerate(collector.procs):
        if not process.is_alive():  # it would never acknowledge the new weights
            raise RuntimeError(
                f"collector worker {index} exited with code {process.exitcode}; its error is "
                "printed above"
            )
    collector.update_policy_weights_(TensorDict.from_module(policy).data)


class CollectorKind(NamedTuple):
    """One ``collector.name``: its schema, how the run builds it, how weights reach it."""

    settings: type
    """The dataclass of ``collector.*`` (checked by ``validate_config``)."""
    make: Callable[[O2ORun, int], BaseCollector]
    """``(run, total_frames) -> collector``, acting with the learner's exploration policy."""
    push: Callable[[BaseCollector, nn.Module], None]
    """``(collector, policy) -> None``, after every update block: the policy's current
    parameters and buffers reach the collector's next batch."""


COLLECTORS: dict[str, CollectorKind] = {
    "single": CollectorKind(CollectorSettings, make_single, push_nothing),
    "multi_sync": CollectorKind(
        MultiCollectorSettings, make_multi(MultiSyncCollector), push_to_processes
    ),
    "multi_async": CollectorKind(
        MultiCollectorSettings, make_multi(MultiAsyncCollector), push_to_processes
    ),
    "ray": CollectorKind(RayCollectorSettings, make_ray, push_to_actors),
}
"""``collector.name`` -> its :class:`CollectorKind`."""


def assign_episodes(
    traj_ids: torch.Tensor, done: torch.Tensor, open_episodes: dict[int, int], next_episode: int
) -> tuple[torch.Tensor, int]:
    """Episode ids of one collected batch from the collector's trajectory ids.

    A trajectory already in ``open_episodes`` (``traj_id -> episode``, its earlier part was
    stored before) keeps its episode; a new one gets the next fresh id, in the order of the
    trajectory ids. ``open_episodes`` is updated in place: trajectories of this batch
    without a ``done`` stay open. Returns the ids and the next fresh id.

    Args:
        traj_ids (torch.Tensor): ``("collector", "traj_ids")`` of the flattened batch.
        done (torch.Tensor): ``("next", "done")`` of the flattened batch, same shape.
        open_episodes (dict[int, int]): the open trajectories' episode ids (updated).
        next_episode (int): the smallest id no episode has yet.

    Examples:
        >>> open_episodes = {}
        >>> traj = torch.tensor([0, 0, 1, 1, 2, 2])  # two workers: 0 then 2, and 1
        >>> done = torch.tensor([False, True, False, False, False, False])
        >>> ids, nxt = assign_episodes(traj, done, open_episodes, 10)
        >>> ids.tolist(), nxt, open_episodes
        ([10, 10, 11, 11, 12, 12], 13, {1: 11, 2: 12})
        >>> done = torch.ones(3, dtype=torch.bool)
        >>> ids, nxt = assign_episodes(torch.tensor([2, 1, 3]), done, open_episodes, nxt)
        >>> ids.tolist(), nxt, open_episodes
        ([12, 11, 13], 14, {})
    """
    traj_ids = traj_ids.reshape(-1)
    done = done.reshape(-1).to(torch.long)
    trajectories, position = torch.unique(traj_ids, return_inverse=True)
    episodes = []
    for traj in trajectories.tolist():
        if traj in open_episodes:
            episodes.append(open_episodes.pop(traj))
        else:
            episodes.append(next_episode)
            next_episode += 1
    episode_of = torch.tensor(episodes, dtype=torch.long)
    ended = torch.zeros(len(trajectories), dtype=torch.long).index_add_(0, position, done)
    for traj, episode, end in zip(trajectories.tolist(), episodes, ended.tolist(), strict=True):
        if not end:
            open_episodes[traj] = episode
    return episode_of[position], next_episode
