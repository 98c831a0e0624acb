"""A shared offline phase: runs that differ only in online settings train it once.

DUAL and its online ablations (``laplace.num_samples=0``, ``exploration.shift_weight=0``,
an online dynamics shift ``env.shift=...``) start from the same planner, distillation and
actor-critic pre-training when env, data, seed and offline settings agree; so does IQL
under every shift. With ``offline_cache=<dir>`` the first such run saves the state right
after its learner's :attr:`~torchrl_dual.recipe.Learner.shared_stages` (networks,
optimizers, counters, RNG, the logger and its CSV files, the stage wall times), and the
others load it instead of recomputing it. A run that loads the snapshot continues exactly
as if it had computed the stages itself: same weights, same random stream (tested).

The key is a hash of the run's config without the keys that only the online phase reads
(:data:`ONLINE_KEYS` and the learner's :attr:`~torchrl_dual.recipe.Learner.online_keys`)
and without where the run writes, and of :data:`OFFLINE_PHASE_REVISION`; a change to any
other key is a different offline phase, and so is a code change that bumps the revision.
A file lock (``fcntl.flock``, released if the process dies) makes parallel runs with the
same key wait for the first one instead of computing it twice.
"""

from __future__ import annotations

import copy
import fcntl
import hashlib
import json
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

from torchrl_dual.checkpoint import CheckpointError, RunCheckpoint
from torchrl_dual.recipe.settings.errors import UserError

if TYPE_CHECKING:
    from torchrl_dual.recipe.o2o.run import O2ORun

OFFLINE_PHASE_REVISION = 1
"""Bumped when a code change alters what a shared offline stage computes, so that caches
written before it are not reused (their entries stay on disk under their old keys)."""

ONLINE_KEYS: tuple[str, ...] = (
    "output_dir",
    "resume",
    "interrupt_at_frames",
    "interrupt_at_offline_updates",  # where a run stops, not what its stages compute
    "offline_cache",
    "data_cache_dir",  # where the data set is cached, not what it holds
    "progress",  # display only
    "debug",  # error display only
    "budget.name",
    "budget.online_frames",
    "budget.frames_per_batch",
    "budget.laplace_refit_every",
    "budget.eval_every",
    "budget.eval_episodes",
    "budget.checkpoint_every",
    "budget.offline_checkpoint_every",  # checkpoints within a stage change nothing in it
    "online.offline_fraction",
    "online.utd_ratio",
    "replay",
    "collector",
    "critic.online_steps_per_update",  # SO2's online critic steps; its offline phase is SAC-N
    "critic.policy_noise",
    "critic.target_reduction",
    "env.shift",
    "env.shift_angle",
    "env.shift_scale",
    "env.start_avoid_cells",  # PointMaze's online and evaluation starts
    "env.online_success_rate",
)
"""Dotted keys that no algorithm's offline stages read (the online phase, the offline
evaluation, which runs after the snapshot on the possibly shifted env, and bookkeeping)."""


def offline_key_config(config: dict, extra_online_keys: tuple[str, ...] = ()) -> dict:
    """The resolved ``config`` without the online-only keys: what a shared offline phase comes from.

    ``config`` is the run's resolved config as plain containers (``O2ORun.config``); it is
    left as it is. Every config key is in :data:`ONLINE_KEYS` or in the record of keyed
    names that ``tests/recipe/test_offline_cache.py`` checks the config against.
    """
    container = copy.deepcopy(config)
    for dotted in (*ONLINE_KEYS, *extra_online_keys):
        node, leaf = _parent(container, dotted)
        if node is not None:
            node.pop(leaf, None)
    return container


def _parent(container: dict, dotted: str) -> tuple[dict | None, str]:
    """The dict holding ``dotted``'s last part, and that part.

    The dict is ``None`` if a parent is missing.
    """
    *parents, leaf = dotted.split(".")
    node = container
    for part in parents:
        node = node.get(part) if isinstance(node, dict) else None
    return (node if isinstance(node, dict) else None), leaf


class OfflinePhaseCache:
    """The snapshot of one shared offline phase under ``root/<key>/``.

    Args:
        root (str or Path): the cache directory (``offline_cache``).
        key_config (dict): :func:`offline_key_config` of the run; its hash names the entry
            and the snapshot's fingerprint must match it on load.
        layout (str): the checkpoint layout of the run (part of the fingerprint).

    Examples:
        >>> import tempfile
        >>> cache = OfflinePhaseCache(tempfile.mkdtemp(), {"seed": 0, "algo": "dual"}, "v1")
        >>> cache.exists()
        False
        >>> with cache.lock():
        ...     cache.save({"weights": [1.0]}, logs_dir=None)
        >>> cache.load()["weights"]
        [1.0]
    """

    def __init__(self, root: str | Path, key_config: dict, layout: str) -> None:
        keyed = {"config": key_config, "revision": OFFLINE_PHASE_REVISION}
        text = json.dumps(keyed, sort_keys=True, default=str)
        self.key = hashlib.sha256(text.encode()).hexdigest()[:16]
        self.directory = Path(root) / self.key
        fingerprint = {"offline_phase": key_config, "checkpoint_layout": layout}
        self._checkpoint = RunCheckpoint(self.directory / "offline_phase.pt", fingerprint)
        self._key_config = key_config

    def exists(self) -> bool:
        """Whether the entry's snapshot has been written."""
        return self._checkpoint.exists()

    @contextmanager
    def lock(self) -> Iterator[None]:
        """Holds an exclusive lock on this entry (blocks while another run holds it)."""
        self.directory.mkdir(parents=True, exist_ok=True)
        with open(self.directory / "lock", "w") as handle:
            fcntl.flock(handle, fcntl.LOCK_EX)
            try:
                yield
            finally:
                fcntl.flock(handle, fcntl.LOCK_UN)

    def save(self, state: dict[str, Any], logs_dir: Path | None) -> None:
        """Writes the snapshot (atomically), a copy of the run's logs and a ``config.json``.

        Call it under :meth:`lock`.
        """
        self.directory.mkdir(parents=True, exist_ok=True)
        if logs_dir is not None and logs_dir.exists():
            target = self.directory / "logs"
            shutil.rmtree(target, ignore_errors=True)
            # a W&B run's files are its own: the next run logs to its own W&B run
            shutil.copytree(logs_dir, target, ignore=shutil.ignore_patterns("wandb"))
        (self.directory / "config.json").write_text(
            json.dumps(self._key_config, indent=1, sort_keys=True, default=str)
        )
        self._checkpoint.save(state)

    def load(self) -> dict[str, Any]:
        """The snapshot (raises ``CheckpointError`` if it is corrupt or another phase's)."""
        return self._checkpoint.load()

    def copy_logs(self, logs_dir: Path) -> None:
        """Puts the offline phase's log files where the run writes its own."""
        source = self.directory / "logs"
        if source.exists():
            shutil.copytree(source, logs_dir, dirs_exist_ok=True)


def run_offline_stages(run: O2ORun) -> None:
    """Runs the learner's offline stages, sharing its shared stages through the offline cache.

    With ``offline_cache`` set, :attr:`Learner.shared_stages` are loaded from the
    snapshot if another run wrote it, else computed and written (under the entry's
    lock); then the remaining stages run.
    """
    learner = run.learner
    stages = learner.offline_stages()
    shared = [(name, fn) for name, fn in stages if name in learner.shared_stages]
    root = run.settings.offline_cache
    todo = [name for name, _ in shared if name not in run.stages_done]
    if root is not None and shared and todo:
        key_config = offline_key_config(run.config, learner.online_keys)
        cache = OfflinePhaseCache(root, key_config, run.checkpoint_layout)
        modules = learner.shared_modules()
        with cache.lock():
            if cache.exists():
                _restore(run, cache, modules)
            else:
                for name, fn in shared:
                    run.stage(name, fn)
                cache.save(run.state(modules), run.output_dir / "logs")
    for name, fn in stages:
        run.stage(name, fn)


def _restore(run: O2ORun, cache: OfflinePhaseCache, modules: dict[str, Any]) -> None:
    """Continues ``run`` from the snapshot: its weights, counters, RNG and logs."""
    try:
        snapshot = cache.load()
    except CheckpointError as err:
        raise UserError(
            "offline_cache",
            str(cache.directory.parent),
            f"the shared offline phase {cache.directory} cannot be read ({err}); delete that "
            "directory to recompute it",
        ) from err
    cache.copy_logs(run.output_dir / "logs")
    # the snapshot's logger state, writing into this run's directory (and W&B run)
    run.make_logger(run.load(snapshot, modules))
    run.shared_offline = True
    run.say(f"offline stages {', '.join(run.stages_done)}: loaded from {cache.directory}")
    run.save()
