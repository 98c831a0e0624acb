"""The online phase's collector (Alg. 1 lines 11-12), a table by ``collector.name``.

* ``single`` (``collector/single.yaml``, the default): TorchRL's
  :class:`~torchrl.collectors.Collector` steps the run's online env in this process with the
  learner's exploration policy; with ``collector.num_envs = N > 1`` it steps N copies as
  one batch (:func:`~torchrl_dual.envs.vectorized_env`), the policy acting for all N in
  one call, each copy ``budget.frames_per_batch / N`` frames of a ``[N, T]`` batch.
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
(a picklable ``() -> env``, so its ``PreviousTransition`` and hence the shift signal
``d_t`` of Eq. (10) follow that worker's own trajectory). The workers act with an *acting copy* of the learner's
exploration policy, whose tensors they share (TorchRL's ``SharedMemWeightSyncScheme``):
the updates never touch it, so an asynchronous worker never reads a network mid-update or a
Laplace posterior mid-refit. The run calls its collector kind's ``push`` after every block
of updates (:func:`push_to_processes`: the current parameters *and buffers*, DUAL's
Laplace posterior draws refitted every ``budget.laplace_refit_every`` updates, copied into
the acting copy); ``multi_sync``'s next batch acts with them, ``multi_async``'s batches in
flight switch over mid-batch. Ray's remote collectors hold their own copies and receive
the same tensors (:func:`~torchrl_dual.recipe.o2o.ray_collector.push_to_actors`).

``collector.device`` (null: the run's ``device``) is where the acting policy runs and the
batches are gathered, apart from where the updates run: with ``device=cuda
collector.device=cpu`` the envs and the policy step on the CPU, and the replay takes the
batches as usual. ``single`` then acts with TorchRL's own copy of the policy on that
device (``Collector`` makes it), refreshed by :func:`push_to_single` after every block of
updates; on one device it acts with the learner's policy itself.

Episode ids: :func:`~torchrl_dual.recipe.o2o.episodes.assign_episodes` maps the
collectors' trajectory ids to the run's episode ids.

Cal-QL's Monte-Carlo labels (``critic=calql``) hold one stream of transitions until its
episode ends: :func:`~torchrl_dual.recipe.settings.o2o.check_streams` refuses them with
several workers. The table :data:`~torchrl_dual.recipe.settings.o2o.COLLECTORS` names the
builders below.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import TYPE_CHECKING

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.collectors import Collector, MultiAsyncCollector, MultiSyncCollector
from torchrl.envs.utils import ExplorationType

from torchrl_dual.recipe.kits.build import TrainEnvFactory

if TYPE_CHECKING:
    from torchrl.collectors import BaseCollector

    from torchrl_dual.recipe.o2o.run import O2ORun
    from torchrl_dual.recipe.settings.structured import RecipeSettings


def collector_device(settings: RecipeSettings) -> torch.device:
    """``collector.device``, or the run's ``device`` where it is null."""
    return torch.device(settings.collector.device or settings.device)


def make_single(run: O2ORun, total_frames: int) -> BaseCollector:
    """TorchRL's ``Collector`` on ``run.collection_env``, seeded, acting on ``collector.device``.

    ``run.collection_env`` is ``run.env``, or its ``collector.num_envs`` copies as one
    batch; it is seeded ``seed + 1 + frames``, copy ``i`` ``seed + 1 + frames + i``. The
    collector acts with a copy of the policy on ``collector.device`` if the learner's is
    elsewhere.
    """
    settings = run.settings
    env = run.collection_env
    env.set_seed(settings.seed + 1 + run.frames)
    return Collector(
        env,
        run.learner.exploration_policy,
        frames_per_batch=settings.budget.frames_per_batch,
        total_frames=total_frames,
        exploration_type=ExplorationType.RANDOM,
        device=collector_device(settings),
        auto_register_policy_transforms=False,
    )


def make_multi(collector_class: type) -> Callable[[O2ORun, int], BaseCollector]:
    """``(run, total_frames) -> collector`` for TorchRL's multi-process ``collector_class``."""

    def make(run: O2ORun, total_frames: int) -> BaseCollector:
        settings = run.settings
        collector = collector_class(
            [TrainEnvFactory(settings, run.data)] * settings.collector.num_workers,
            copy.deepcopy(run.learner.exploration_policy),  # the acting copy
            frames_per_batch=settings.budget.frames_per_batch,
            total_frames=total_frames,
            exploration_type=ExplorationType.RANDOM,
            device=collector_device(settings),
            num_threads=settings.num_threads,  # this process's threads (TorchRL would lower them)
            auto_register_policy_transforms=False,
        )
        try:  # worker 0 gets seed + 1 + frames, the others TorchRL's chained seeds
            collector.set_seed(settings.seed + 1 + run.frames)
        except BaseException:
            collector.shutdown()
            raise
        return collector

    return make


make_multi_sync = make_multi(MultiSyncCollector)
"""``collector=multi_sync``: TorchRL's ``MultiSyncCollector`` (batches stacked)."""
make_multi_async = make_multi(MultiAsyncCollector)
"""``collector=multi_async``: TorchRL's ``MultiAsyncCollector`` (first come)."""


def stop_collecting(collector: BaseCollector) -> None:
    """Ends ``collector`` at a cut point of the online loop.

    Its workers stop; the run's own env (``collector=single``) stays open for the next
    collector, which re-seeds it.
    """
    if isinstance(collector, Collector):
        collector.shutdown(close_env=False)
    else:
        collector.shutdown()


def push_to_single(collector: BaseCollector, policy: nn.Module) -> None:
    """Pushes ``policy``'s weights to a ``collector=single`` collector acting on another device.

    Nothing to push where it acts with ``policy`` itself (one device); else TorchRL's
    ``update_policy_weights_`` copies ``policy``'s parameters and buffers into the
    collector's copy on ``collector.device``.
    """
    if collector.policy is not policy:
        collector.update_policy_weights_(TensorDict.from_module(policy).data)


def push_to_processes(collector: BaseCollector, policy: nn.Module) -> None:
    """Copies ``policy``'s current parameters and buffers into the collector's acting copy.

    The worker processes share that copy.

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
