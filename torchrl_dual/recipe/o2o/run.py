"""The algorithm-independent offline-to-online run, and the :class:`Learner` it drives.

:class:`O2ORun` owns what every offline-to-online algorithm of the recipe shares: the
seeds, the offline data, the online env and the evaluator, the offline replay buffer and
TorchRL's ``OfflineToOnlineReplayBuffer``, the logger, the counters, the collector, the
counted update (``run.update``, :class:`~torchrl_dual.recipe.o2o.update_step.LearnerUpdates`),
evaluation, checkpoint and resume, and the report at the end. What is particular to one
algorithm (its networks, its offline stages, one gradient update, the acting policies) is
a :class:`Learner`; :func:`run_o2o` runs one learner through the offline and the online
phase on TorchRL's ``Trainer``. Each entry of :data:`~torchrl_dual.recipe.ALGORITHMS` is
a learner class and a config file.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase
from torchrl.collectors import BaseCollector
from torchrl.data import LazyTensorStorage, RandomSampler, ReplayBuffer
from tqdm.auto import tqdm

from torchrl_dual._tensordict_patch import install as install_tensordict_patch
from torchrl_dual.checkpoint import CheckpointError, RunCheckpoint, rng_state, set_rng_state
from torchrl_dual.data import TRANSITION_KEYS
from torchrl_dual.recipe.kits import build as env_kits
from torchrl_dual.recipe.o2o.episodes import assign_episodes
from torchrl_dual.recipe.o2o.interrupts import held
from torchrl_dual.recipe.o2o.learner import Learner
from torchrl_dual.recipe.o2o.loggers import make_logger
from torchrl_dual.recipe.o2o.run_lock import acquire_run_directory
from torchrl_dual.recipe.o2o.stage_checkpoints import StageCheckpoints
from torchrl_dual.recipe.o2o.stage_clock import StageClock
from torchrl_dual.recipe.o2o.summary import report_finished_run, score_text
from torchrl_dual.recipe.o2o.update_step import LearnerUpdates
from torchrl_dual.recipe.settings.errors import UserError
from torchrl_dual.recipe.settings.o2o import COLLECTORS, REPLAYS, check_output_dir
from torchrl_dual.recipe.settings.structured import RecipeSettings

# Settings that may change when a run is resumed; everything else must match.
RESUMABLE_KEYS = (
    "output_dir",  # a run directory may be moved (or copied) and resumed where it is
    "data_cache_dir",  # the data is regenerated identically from its seed, or read
    "resume",
    "progress",
    "interrupt_at_frames",
    "interrupt_at_offline_updates",
    "num_threads",
    "device",
    "debug",
    "offline_cache",
    "collector",  # how frames are gathered: a resumed run may use other workers or cores
    "compile",  # how an update runs (compiled or not), not what it computes
)
# Part of the fingerprint: a checkpoint of another layout is refused ("incompatible run").
CHECKPOINT_LAYOUT = "o2o-learner-3"
_COUNTERS = (
    "stages_done",
    "stage_seconds",
    "stage_cpu_seconds",
    "shared_offline",
    "frames",
    "updates",
    "update_credit",
    "next_episode",
    "history",
    "online_signals",
    "offline_steps",
)


class O2ORun:
    """Everything one offline-to-online run needs apart from its :class:`Learner`.

    ``cfg`` must have passed :func:`~torchrl_dual.recipe.validate_config`;
    ``make_learner`` is ``run -> Learner`` (usually the learner class). The run reads
    ``cfg`` as :attr:`settings` (typed, for the run, its env kit and learner) and
    :attr:`config` (plain: the fingerprint, ``summary.json``, the offline cache's key).

    Examples:
        >>> import contextlib, io, tempfile
        >>> from torchrl_dual.recipe import CONFIG_DIR, IQLLearner, compose_checked
        >>> out = tempfile.mkdtemp()
        >>> cfg = compose_checked(CONFIG_DIR, [
        ...     "algo=iql", "env=frozenlake", "budget=smoke", "progress=false",
        ...     f"output_dir={out}/run", f"data_cache_dir={out}/data",
        ...     "budget.dataset_transitions=1000"])
        >>> with contextlib.redirect_stdout(io.StringIO()):
        ...     run = O2ORun(cfg, IQLLearner)  # data, env, evaluator, learner, replay
        >>> len(run.data), run.data.obs_dim, run.frames, run.updates
        (1000, 16, 0, 0)
        >>> type(run.learner).__name__, [name for name, _ in run.learner.offline_stages()]
        ('IQLLearner', ['actor_critic'])
    """

    def __init__(self, cfg: DictConfig, make_learner: Callable[[O2ORun], Learner]) -> None:
        self.settings = settings = RecipeSettings.of(cfg)
        self.config: dict[str, Any] = OmegaConf.to_container(cfg, resolve=True)
        self.name = settings.algo
        torch.set_num_threads(settings.num_threads)
        install_tensordict_patch()  # TensorDictModule outputs without a sys.path scan each
        self.seed_everything(settings.seed)
        self.output_dir = Path(settings.output_dir)
        fingerprint = {k: v for k, v in self.config.items() if k not in RESUMABLE_KEYS}
        fingerprint["checkpoint_layout"] = self.checkpoint_layout = CHECKPOINT_LAYOUT
        budget = fingerprint["budget"] = dict(fingerprint["budget"])
        budget.pop("offline_checkpoint_every", None)  # may change on resume
        acquire_run_directory(settings.output_dir)  # one run per directory (o2o/run_lock.py)
        check_output_dir(settings.output_dir, settings.resume)  # locked: no other writer now
        self.checkpoint = RunCheckpoint(
            self.output_dir / "checkpoint.pt", fingerprint, free_keys=RESUMABLE_KEYS
        )
        # Read a checkpoint first, so a corrupt or incompatible one fails before any work.
        saved = self._load_checkpoint() if settings.resume and self.checkpoint.exists() else None
        if settings.resume and saved is None:
            self.say(f"resume=true: no checkpoint in {self.output_dir}; starting a new run")
        # ---- data and envs (Alg. 1 line 1)
        self.data = env_kits.make_offline_dataset(settings)
        self.env = env_kits.make_train_env(settings, self.data)
        env_kits.check_dims(self.env, self.data, settings.env.name)
        # what collector=single steps: the env, or collector.num_envs copies as one batch
        self.collection_env = env_kits.make_collection_env(settings, self.data, self.env)
        self.evaluate_policy = env_kits.make_evaluator(settings, self.data)
        self.offline_buffer = self._offline_buffer()
        # ---- the algorithm's networks, losses and policies
        self.learner = make_learner(self)
        self.update = LearnerUpdates(self)  # one counted update; the trainer's stepper
        self.replay = REPLAYS[settings.replay.name][1](self)  # D_offline ∪ D_online (replays.py)
        # ---- counters
        self.stages_done: list[str] = []
        self.stage_seconds: dict[str, float] = {}  # wall-clock seconds per stage
        self.stage_cpu_seconds: dict[str, float] = {}  # this process's CPU seconds per stage
        self.shared_offline = False
        self.frames = 0
        self.updates = 0
        self.update_credit = 0.0
        self.next_episode = int(self.data.transitions["episode"].max()) + 1  # a fresh id
        self.open_episodes: dict[int, int] = {}  # collector trajectory id -> its episode id
        self.history: list[dict] = []
        self.online_signals: list[dict] = []  # per collected batch (plots.online_signals)
        self.offline_steps = 0  # updates of the offline stages' loops (stage_checkpoints)
        self.stage_progress: dict | None = None  # the running stage's loop, when saved
        self.current_stage: str | None = None
        self.stage_clock: StageClock | None = None
        self.stopped_at: str | None = None  # where an interrupt saved the running stage
        logger_state = self.load(saved) if saved is not None else None
        self.make_logger(logger_state)

    def make_logger(self, state: dict | None = None) -> None:
        """The ``logger.backend`` TorchRL logger under ``output_dir/logs``.

        It continues ``state``, if given; it replaces and closes the current one.
        """
        previous = getattr(self, "logger", None)
        self.logger = make_logger(
            self.settings.logger, self.output_dir / "logs", self.name, state, previous, self.config
        )

    # ------------------------------------------------------------------ bookkeeping
    @staticmethod
    def seed_everything(seed: int) -> None:
        """Seeds Python's, NumPy's and torch's random number generators with ``seed``."""
        random.seed(seed)
        np.random.seed(seed)
        torch.manual_seed(seed)

    def say(self, text: str) -> None:
        """Prints ``text`` on one line, prefixed by the run's name."""
        print(f"[{self.name}] {text}")

    def _offline_buffer(self) -> ReplayBuffer:
        """Uniform transitions from D_offline, as a plain ``ReplayBuffer``.

        Its samples carry the same keys as the online part of
        ``OfflineToOnlineReplayBuffer``.
        """
        buffer = ReplayBuffer(
            storage=LazyTensorStorage(len(self.data), device=self.settings.device),
            sampler=RandomSampler(),
            batch_size=self.settings.online.batch_size,
        )
        buffer.extend(self.data.transitions)
        return buffer

    def refresh_offline_buffer(self) -> None:
        """Rebuilds :attr:`offline_buffer` from ``data``.

        A learner that relabels the offline transitions (e.g. Cal-QL's Monte-Carlo
        bound) calls it.
        """
        self.offline_buffer = self._offline_buffer()

    def state(self, modules: dict[str, Any] | None = None) -> dict[str, Any]:
        """Everything needed to continue the run.

        ``modules`` (default: the learner's, and then the replay's state too),
        counters, online data, RNG and logger state. A shared offline phase passes
        its ``modules`` and leaves the replay out: the replay is online-only.
        """
        online = self.replay.online_buffer
        state = {} if modules is not None else {"replay": self.replay.state_dict()}
        modules = self.learner.modules() if modules is None else modules
        state.update({name: module.state_dict() for name, module in modules.items()})
        state.update({name: getattr(self, name) for name in _COUNTERS})
        state.update(
            learner=self.learner.state_dict(),
            online_data=online[: len(online)].clone() if len(online) else None,
            rng=rng_state(),
            logger=self.logger.state_dict() if hasattr(self.logger, "state_dict") else None,
            stage_progress=self.stage_progress,
        )
        return state

    def save(self) -> None:
        """Checkpoints :meth:`state` (atomic write)."""
        self.checkpoint.save(self.state())

    def _load_checkpoint(self) -> dict:
        try:
            return self.checkpoint.load()
        except CheckpointError as err:  # corrupt, not a checkpoint, or another run's settings
            raise UserError("resume", True, str(err)) from err

    def load(self, state: dict | None = None, modules: dict[str, Any] | None = None):
        """Restores the checkpoint's ``state`` into ``modules``; returns the logger's state.

        ``state`` is read if not given; ``modules`` defaults to the learner's.
        """
        state = self._load_checkpoint() if state is None else state
        modules = self.learner.modules() if modules is None else modules
        try:
            for name, module in modules.items():
                module.load_state_dict(state[name])
            self.learner.load_state_dict(state["learner"])
        except (KeyError, RuntimeError, ValueError) as err:
            raise UserError(
                "resume",
                True,
                f"the checkpoint {self.checkpoint.path} does not fit this run's networks "
                f"({err}). Resume with the settings that wrote it, or use another output_dir.",
            ) from err
        for name in _COUNTERS:
            setattr(self, name, state[name])
        self.stage_progress = state.get("stage_progress")
        if state["online_data"] is not None:
            self.replay.extend(state["online_data"])
            # next_episode (a counter above) is past every id handed out, stored or held
            # by the learner (Cal-QL's MonteCarloLabels): the collector's new episode
            # after the resume takes it, the cut one keeps its own.
        if "replay" in state:  # after the online data: the priorities follow it
            self.replay.load_state_dict(state["replay"])
        set_rng_state(state["rng"])
        return state["logger"]

    def stage(self, name: str, fn: Callable[[], Any]) -> None:
        """Runs one offline stage unless a resumed run already did it; then checkpoints.

        A resumed stage continues its update loop from a checkpoint within it, if
        there is one.
        """
        if name in self.stages_done:
            self.say(f"{name}: done in the checkpoint, skipped")
            return
        self.current_stage = name
        clock = self.stage_clock = StageClock(self.stage_seconds, self.stage_cpu_seconds, name)
        progress = self.stage_progress
        if progress is not None and progress["stage"] == name:
            self.say(f"{name}: continues from update {progress['done']}/{progress['total']}")
        else:
            self.say(f"{name}: started")
        fn()
        clock.tick()
        self.say(
            f"{name}: done in {self.stage_seconds[name]:.0f} s "
            f"({self.stage_cpu_seconds[name]:.0f} CPU-s)"
        )
        self.stages_done.append(name)
        self.current_stage = self.stage_progress = None
        self.save()

    @contextmanager
    def stage_checkpoints(self) -> Iterator[StageCheckpoints | None]:
        """The running offline stage's :class:`StageCheckpoints`, for its update loop.

        The ``checkpoints=`` of ``run_updates``; Ctrl-C and SIGTERM stop the loop
        after an update (:func:`~torchrl_dual.recipe.o2o.interrupts.held`). ``None``
        outside a stage (a learner's stage method called on its own).
        """
        with held():
            yield None if self.current_stage is None else StageCheckpoints(self)

    def log(self, values: dict, step: int, prefix: str) -> None:
        """Logs each of ``values`` as ``{prefix}{key}`` at ``step``."""
        for key, value in values.items():
            self.logger.log_scalar(f"{prefix}{key}", float(value), step=step)

    def all_transitions(self, chunk: int = 8192):
        """D_offline then D_online, in chunks on the run's device."""
        for source in (self.data.transitions, self.replay.online_buffer):
            for start in range(0, len(source), chunk):
                yield source[start : start + chunk].to(self.settings.device)

    # ------------------------------------------------------------------ updates
    def pretrain_updates(self) -> None:
        """``budget.offline_updates`` updates on D_offline (DUAL: Alg. 1 lines 6-8).

        Checkpointed within (:meth:`stage_checkpoints`; the weights, optimizers,
        counters and random state are the run's own state).
        """
        total = self.settings.budget.offline_updates
        tenth = max(total // 10, 1)
        with self.stage_checkpoints() as checkpoints:
            saved = None if checkpoints is None else checkpoints.resume()
            start = 0 if saved is None else saved["done"]
            bar = tqdm(
                range(start, total),
                desc="actor+critic",
                disable=not self.settings.progress,
                leave=False,
                initial=start,
                total=total,
            )
            for i in bar:
                metrics = self.update(self.offline_buffer.sample().to(self.settings.device))
                if i % 100 == 0:
                    self.log(metrics, self.updates, "offline/")
                    if "loss_actor" in metrics:
                        bar.set_postfix(actor=f"{metrics['loss_actor']:.3f}")
                if not self.settings.progress and (i + 1) % tenth == 0:  # no bar: a line per 10 %
                    self.say(f"actor+critic: {i + 1}/{total} updates")
                if checkpoints is not None:
                    checkpoints.after_update(i + 1, total, lambda done=i + 1: {"done": done})

    def evaluate(self, label: str) -> dict:
        """Evaluates the learner's evaluation policy, logs and prints the result; returns it.

        The result (``return``, ``normalized_score``, ...) gets ``frames`` and ``label`` and is
        appended to the run's history.
        """
        result = self.evaluate_policy(self.learner.evaluation_policy)
        result.update(frames=self.frames, label=label)
        self.history.append(result)
        self.log({k: v for k, v in result.items() if k != "label"}, self.frames, "eval/")
        unshifted = result.get("normalized_score_unshifted")  # under env.shift only
        self.say(
            f"{label} @ {self.frames} frames: normalized score "
            f"{score_text(result['normalized_score'])} (return {result['return']:.3f})"
            + ("" if unshifted is None else f"; without the shift {score_text(unshifted)}")
        )
        return result

    # ------------------------------------------------------------------ online phase
    def collector(self) -> BaseCollector:
        """A collector acting with the learner's exploration policy online (Alg. 1 l. 11-12).

        The ``collector.name`` entry of
        :data:`~torchrl_dual.recipe.settings.o2o.COLLECTORS`.
        """
        remaining = max(self.settings.budget.online_frames - self.frames, 0)
        self.open_episodes = {}  # a new collector starts new trajectories
        self.learner.collector_started()  # its episode in progress ends, its critic is online
        return COLLECTORS[self.settings.collector.name].make(self, remaining)

    def store(self, batch: TensorDictBase) -> dict:
        """D_online ← D_online ∪ {(s_t, a_t, s_t+1, r_t)} with the executed action (l. 13)."""
        batch = batch.reshape(-1)  # [workers, T] (multi_sync), [num_envs, T] or [T]
        episode, self.next_episode = assign_episodes(
            batch["collector", "traj_ids"],
            batch["next", "done"],
            self.open_episodes,
            self.next_episode,
        )
        keys = [k for k in TRANSITION_KEYS if k != "episode"]
        online = batch.select(*keys).clone()
        online.set("episode", episode)
        online = self.learner.online_transitions(online)
        if len(online):
            self.replay.extend(online.cpu())
        self.frames += batch.numel()
        return {
            "reward_per_step": float(batch["next", "reward"].mean()),
            **self.learner.batch_metrics(batch),
        }

    def finish(self) -> None:
        """Checkpoints, closes the logger, then writes and prints what the run measured.

        ``summary.json``, the learning curve and the final scores
        (:func:`~torchrl_dual.recipe.o2o.summary.report_finished_run`).
        """
        self.save()
        self.logger.shutdown()
        report_finished_run(self)
