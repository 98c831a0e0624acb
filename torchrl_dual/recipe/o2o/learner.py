"""The protocol of one algorithm in the offline-to-online recipe: :class:`Learner`.

:class:`~torchrl_dual.recipe.O2ORun` owns what every algorithm shares (data, envs,
replay, collector, UTD schedule, evaluation, checkpoints); a learner adds the networks,
the offline stages, one gradient update and the acting policies. ``DualLearner``
(Algorithm 1) and the baselines' learners implement it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from typing import Any, Protocol

import torch
from tensordict import TensorDictBase
from torch import nn


class RunContext(Protocol):
    """What a learner and the parts it builds may use of the run.

    The run is an :class:`~torchrl_dual.recipe.O2ORun`; they may use its typed config, data
    and env, counters, buffers, logging and the two helpers below.
    ``tests/test_import_layering.py`` checks that ``recipe/algos`` and ``recipe/parts``
    read nothing else of it.

    Attributes:
        settings (RecipeSettings): the validated config, typed: what learners read
            (``settings.actor``, ``settings.budget``, ``settings.device``, ...), never
            the raw ``DictConfig``.
        data (OfflineDataset): ``D_offline``.
        env (EnvBase): the online env (its ``action_spec``).
        frames (int): online frames collected so far (0 in the offline phase).
        updates (int): gradient updates so far.
        logger: the TorchRL logger (for the offline stages' own loops).
        replay: the online replay (``online_buffer``, ``extend``).
        offline_buffer: uniform transitions of ``D_offline``.
    """

    settings: Any
    data: Any
    env: Any
    frames: int
    updates: int
    logger: Any
    replay: Any
    offline_buffer: Any

    def log(self, values: dict, step: int, prefix: str) -> None:
        """Logs ``values`` as scalars under ``prefix``."""

    def all_transitions(self, chunk: int = 8192) -> Iterator[TensorDictBase]:
        """``D_offline`` then ``D_online``, in chunks on the run's device."""

    def pretrain_updates(self) -> None:
        """``budget.offline_updates`` learner updates on ``D_offline``."""

    def refresh_offline_buffer(self) -> None:
        """Rebuilds ``offline_buffer`` from ``data`` (after the learner relabelled it)."""

    def stage_checkpoints(self) -> AbstractContextManager[Any]:
        """The running offline stage's checkpoints, for its update loop's ``checkpoints=``.

        Use as ``with run.stage_checkpoints() as checkpoints:`` around an offline
        stage's update loop: an ``UpdateCheckpoints``, or ``None`` outside a stage.
        """


class Learner(ABC):
    """What one algorithm adds to an :class:`O2ORun`.

    A learner is built by the run (``Learner(run)``) once the run's data, env and
    offline buffer exist, and before its replay buffer, counters and logger; it builds
    its networks, losses and optimizers in ``__init__`` and may keep ``run`` to read
    ``run.settings``, ``run.data``, ``run.logger`` or ``run.updates`` later.

    Attributes:
        title (str): the algorithm's name in the plot title.
        exploration_policy (nn.Module): what the collector runs, under
            ``ExplorationType.RANDOM``; it writes the executed ``"action"`` (after the env
            kit's ``action_projection``, if any).
        evaluation_policy (nn.Module): what the evaluator runs, under
            ``ExplorationType.DETERMINISTIC``.

    Examples:
        A learner that acts with a fixed random linear policy and learns nothing, run for
        100 online frames of Frozen-Lake:

        >>> import contextlib, io, tempfile
        >>> from tensordict.nn import TensorDictModule
        >>> from torch import nn
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked, run_o2o
        >>> class LinearPolicyLearner(Learner):
        ...     title = "random linear policy"
        ...     def __init__(self, run):
        ...         net = nn.Linear(run.data.obs_dim, run.data.action_dim)
        ...         policy = TensorDictModule(net, in_keys=["observation"], out_keys=["action"])
        ...         self.exploration_policy = self.evaluation_policy = policy
        ...     def modules(self):
        ...         return {}
        ...     def offline_stages(self):
        ...         return []
        ...     def update(self, batch):
        ...         return {}
        >>> out = tempfile.mkdtemp()
        >>> cfg = compose_checked(CONFIG_DIR, [
        ...     "env=frozenlake", "budget=smoke", "progress=false", f"output_dir={out}/run",
        ...     f"data_cache_dir={out}/data", "budget.dataset_transitions=1000",
        ...     "budget.online_frames=100", "budget.frames_per_batch=50", "budget.eval_episodes=1"])
        >>> with contextlib.redirect_stdout(io.StringIO()):  # the run's progress lines
        ...     run = run_o2o(cfg, LinearPolicyLearner)
        >>> run.frames, run.stages_done, [point["frames"] for point in run.history]
        (100, ['offline_eval'], [0, 100])
    """

    title: str = "?"
    exploration_policy: nn.Module
    evaluation_policy: nn.Module
    shared_stages: tuple[str, ...] = ()
    """The leading offline stages that runs differing only in online keys may share
    (``offline_cache``); empty: this learner never shares its offline phase."""
    online_keys: tuple[str, ...] = ()
    """Dotted config keys of this algorithm that its :attr:`shared_stages` do not read
    (beyond :data:`~torchrl_dual.recipe.o2o.offline_cache.ONLINE_KEYS`)."""

    extra_online_capacity: int = 0
    """Online transitions the learner adds beyond the collected frames (planner
    augmentation, :func:`~torchrl_dual.recipe.parts.planner_augment.augment_capacity`): the
    online buffer holds ``budget.online_frames`` plus these, so none overwrites another."""

    online_batches_per_update: int = 1
    """Batches each online update gets: ``k > 1`` passes ``[k, B]`` (``k`` batches of
    D_offline ∪ D_online stacked) to :meth:`update`, e.g. SO2's ``k`` critic steps per
    actor step (``critic.online_steps_per_update``); offline updates always get ``[B]``."""

    @abstractmethod
    def modules(self) -> dict[str, Any]:
        """What the checkpoint holds, each weight once: name -> networks, losses, optimizers.

        Each object has ``state_dict``/``load_state_dict``.
        """

    @abstractmethod
    def offline_stages(self) -> list[tuple[str, Callable[[], None]]]:
        """The offline phase as ordered ``(name, fn)`` stages.

        Each is checkpointed when done and skipped on resume; a stage's update loop
        is checkpointed within it through ``run.stage_checkpoints()``.
        :meth:`O2ORun.pretrain_updates` is the shared ``budget.offline_updates``
        stage. The run appends ``offline_eval``.
        """

    @abstractmethod
    def update(self, batch: TensorDictBase) -> dict[str, torch.Tensor | float]:
        """One gradient update (critic and actor) on ``batch``; returns its metrics.

        The metrics are detached 0-dim tensors, left on the device:
        :meth:`O2ORun.log` reads them back only when it logs, every 100 updates, so
        an update never syncs the host.
        """

    def after_update(self) -> None:  # noqa: B027 - optional hook
        """Called after each :meth:`update`, outside its compiled or CUDA-graph step.

        The update's Python bookkeeping (DUAL counts the updates since its last
        refit). An update whose algorithm allows ``compile.cudagraphs`` leaves every
        Python attribute as it was, since a CUDA graph replays its kernels only.
        """

    def after_updates(self) -> None:  # noqa: B027 - optional hook
        """Called after each block of online updates (DUAL refits its Laplace posterior)."""

    def collector_started(self) -> None:  # noqa: B027 - optional hook
        """Called when a collector starts: the updates from here on are online ones.

        A collector starts at the online phase's start, each checkpoint's cut point
        and a resume. The episode in progress ends at its last transition (Cal-QL's
        labels release it, truncated) and a critic with online settings takes them (SO2's).
        """

    def shared_modules(self) -> dict[str, Any]:
        """What a shared offline phase hands over (defaults to :meth:`modules`).

        Leave out what depends on :attr:`online_keys` (e.g. DUAL's ``M`` posterior
        draws).
        """
        return self.modules()

    def online_transitions(self, transitions: TensorDictBase) -> TensorDictBase:
        """What of the collected ``transitions`` enters ``D_online`` now (Alg. 1 l. 13).

        All of them by default. Cal-QL holds an episode until it ends to label it.
        """
        return transitions

    def batch_metrics(self, batch: TensorDictBase) -> dict[str, float]:
        """Metrics of a collected batch beyond ``reward_per_step`` (logged under ``online/``)."""
        return {}

    def state_dict(self) -> dict[str, Any]:
        """The learner's counters that are not in :meth:`modules` (checkpointed)."""
        return {}

    def load_state_dict(self, state: dict[str, Any]) -> None:  # noqa: B027 - optional
        """Restores what :meth:`state_dict` returned."""
