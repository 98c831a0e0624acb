"""``collector=ray``: the online phase's collection (Alg. 1 lines 11-12) on a Ray cluster.

TorchRL's :class:`~torchrl.collectors.distributed.RayCollector` with
``collector.num_workers`` remote collectors: Ray actors of one CPU each, placed by Ray on
any node of the cluster, each a TorchRL :class:`~torchrl.collectors.Collector` stepping
one env that it builds with :class:`~torchrl_dual.recipe.kits.build.TrainEnvFactory` (its
own ``PreviousTransition``, so the shift signal ``d_t`` of Eq. (10) follows that actor's
trajectory) and acting with its own copy of the learner's exploration policy.
``collector.sync=true`` stacks one batch of ``budget.frames_per_batch / num_workers``
frames per actor (as ``multi_sync``), ``false`` hands the run whichever actor's
``budget.frames_per_batch`` frames are ready first (as ``multi_async``).

* **Runtime.** ``collector.address=null`` calls ``ray.init(address=None)``: the cluster
  named by ``RAY_ADDRESS``, else the one ``ray start`` runs on this machine, else a new
  local runtime on this machine's cores; a string is passed as it is (``auto``,
  ``<head-ip>:6379``, ``ray://...``). A runtime this process already initialized is used
  as it is. TorchRL's runtime lease ends (``ray.shutdown``) what the collector initialized
  when the run shuts the collector down: a local runtime stops, a cluster is only
  disconnected from; a runtime initialized before the run is left running.
* **Weights.** :func:`push_to_actors` sends the policy's parameters *and buffers*
  (DUAL's Laplace posterior draws) to every actor after each update block (TorchRL's
  ``RayWeightSyncScheme``: Ray carries the signal, a Gloo process group between the run
  and the actors the tensors). An actor runs one call at a time, so with ``sync=false`` a
  push waits for the batches in flight: every batch acts with one set of weights.
* **Trajectory ids.** Each remote collector numbers its trajectories from 0, so the ids
  of two actors would collide; :class:`InterleavedTrajectories` gives actor ``i`` of
  ``n`` the ids ``i, i + n, i + 2n, ...``, unique across actors, which
  :func:`~torchrl_dual.recipe.o2o.episodes.assign_episodes` maps to the run's episode ids.
* **Seeds.** Actor 0 is seeded ``seed + 1 + frames``, the others with the seeds TorchRL's
  ``set_seed`` chains from it (as the process collectors).

Ray is imported only when the run builds this collector; without it the config check
stops with ``pip install "torchrl-dual[ray]"`` (:func:`check_ray_collector`).
"""

from __future__ import annotations

import copy
from typing import TYPE_CHECKING

import torch
from tensordict import TensorDict
from torch import nn
from torchrl.envs.utils import ExplorationType

from torchrl_dual.recipe.kits.build import TrainEnvFactory
from torchrl_dual.recipe.settings.errors import UserError

if TYPE_CHECKING:
    from torchrl.collectors import BaseCollector

    from torchrl_dual.recipe.o2o.run import O2ORun


class InterleavedTrajectories:
    """Trajectory ids of remote collector ``worker`` of ``workers`` (TorchRL's ``traj_pool=``).

    ``worker``, ``worker + workers``, ``worker + 2 * workers``, ...

    Args:
        worker (int): this collector's index in ``[0, workers)``.
        workers (int): the number of remote collectors.

    Examples:
        >>> pool = InterleavedTrajectories(1, 3)
        >>> pool.get_traj_and_increment(2).tolist(), pool.get_traj_and_increment().tolist()
        ([1, 4], [7])
        >>> other = InterleavedTrajectories(1, 3)
        >>> other.load_state_dict(pool.state_dict())
        >>> other.get_traj_and_increment().tolist()
        [10]
    """

    def __init__(self, worker: int, workers: int) -> None:
        self.worker, self.workers, self.count = worker, workers, 0

    def get_traj_and_increment(
        self, n: int | torch.Tensor = 1, device: torch.device | None = None
    ) -> torch.Tensor:
        """The next ``n`` ids of this collector."""
        n = int(n)
        ids = self.worker + self.workers * torch.arange(self.count, self.count + n)
        self.count += n
        return ids.to(device)

    def state_dict(self) -> dict[str, int]:
        """How many ids were handed out (the collector's ``state_dict`` keeps it)."""
        return {"count": self.count}

    def load_state_dict(self, state: dict[str, int]) -> None:
        """Continues after the ids ``state`` had handed out."""
        self.count = int(state["count"])


def make_ray(run: O2ORun, total_frames: int) -> BaseCollector:
    """TorchRL's ``RayCollector`` for ``run``, seeded, with the policy's weights already pushed.

    ``collector.num_workers`` actors; the weight channel is connected before the first
    batch.
    """
    from torchrl.collectors.distributed import RayCollector  # imports ray

    settings, section = run.settings, run.settings.collector
    workers = section.num_workers
    try:
        collector = RayCollector(
            [TrainEnvFactory(settings, run.data)] * workers,
            copy.deepcopy(run.learner.exploration_policy),  # what the actors are sent
            frames_per_batch=settings.budget.frames_per_batch,
            total_frames=total_frames,
            exploration_type=ExplorationType.RANDOM,
            device="cpu",
            sync=section.sync,
            collector_kwargs=[
                {
                    "traj_pool": InterleavedTrajectories(worker, workers),
                    "auto_register_policy_transforms": False,
                }
                for worker in range(workers)
            ],
            remote_configs={"num_cpus": 1},
            ray_init_config={
                "address": section.address,
                "include_dashboard": False,
                "log_to_driver": False,
            },
        )
    except ConnectionError as error:
        raise UserError(
            "collector.address",
            section.address,
            f"{error} Start a cluster (ray start --head) or use collector.address=null "
            "for a local Ray runtime",
        ) from None
    try:  # actor 0 gets seed + 1 + frames, the others TorchRL's chained seeds
        collector.set_seed(settings.seed + 1 + run.frames)
        push_to_actors(collector, run.learner.exploration_policy)
    except BaseException:
        collector.shutdown()
        raise
    return collector


def push_to_actors(collector: BaseCollector, policy: nn.Module) -> None:
    """Sends ``policy``'s current parameters and buffers to every remote collector.

    Returns once each has loaded them (an actor busy collecting loads them after its
    batch).
    """
    collector.update_policy_weights_(TensorDict.from_module(policy).data)
