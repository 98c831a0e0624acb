"""The schema of the offline-to-online run's own parts, with their checks.

The online replay (:data:`REPLAYS`), the collector (:data:`COLLECTORS`) and the output
directory; the metrics logger's is in :mod:`~torchrl_dual.recipe.settings.loggers`.

Builders are :class:`~torchrl_dual.recipe.settings.lazy.Ref` s into
:mod:`torchrl_dual.recipe.o2o`, imported when a run starts.
"""

from __future__ import annotations

import importlib.util
import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

from omegaconf import DictConfig

from torchrl_dual.recipe.settings.errors import ConfigError
from torchrl_dual.recipe.settings.lazy import Ref
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.recipe.settings.rules import Flag, Integer, Maybe, Real, Text, key


@dataclass
class ReplaySettings:
    """``replay/mixed.yaml``: the name only (the offline share is ``online.offline_fraction``)."""

    name: str = key(
        Text(),
        "the `REPLAYS` entry, chosen with `replay=<name>` (default `mixed`): where the online "
        "updates' batches come from (the offline phase samples `D_offline` uniformly). `mixed`: "
        "TorchRL's `OfflineToOnlineReplayBuffer`, a fixed share `online.offline_fraction` of "
        "each batch from `D_offline`, the rest from `D_online`; `balanced`: OFF2ON's "
        "density-ratio priorities over `D_offline ∪ D_online` (`online.offline_fraction` is not "
        "read); it works with every algorithm, `algo=so2` selects it",
    )


@dataclass
class BalancedReplaySettings(ReplaySettings):
    """``replay/balanced.yaml``: OFF2ON's density-ratio network and priorities."""

    temperature: float = key(Real(0, low_open=True), "`T` of the priorities `w^(1/T)` (OFF2ON: 5)")
    hidden: int = key(Integer(1), "MLP width of the density-ratio network (OFF2ON's)")
    depth: int = key(Integer(1), "hidden layers of the density-ratio network (OFF2ON's)")
    lr: float = key(
        Real(0, low_open=True), "Adam learning rate of the density-ratio network (OFF2ON's)"
    )
    ratio_batch_size: int = key(
        Integer(1),
        "offline and online transitions (each) per density-ratio network step (OFF2ON: 256)",
    )


class ReplayKind(NamedTuple):
    """One ``replay.name``: its schema and its builder."""

    settings: type
    """The dataclass of ``replay.*`` (checked by ``validate_config``)."""
    make: Callable[..., Any]
    """``run -> Replay`` (:class:`~torchrl_dual.recipe.o2o.replays.Replay`)."""


_REPLAYS = "torchrl_dual.recipe.o2o.replays"

REPLAYS: dict[str, ReplayKind] = {
    "mixed": ReplayKind(ReplaySettings, Ref(f"{_REPLAYS}:make_mixed_replay")),
    "balanced": ReplayKind(BalancedReplaySettings, Ref(f"{_REPLAYS}:BalancedReplay")),
}
"""``replay.name`` -> its :class:`ReplayKind`."""


@dataclass
class CollectorSettings:
    """``collector/single.yaml`` (one process, the run's own env); every collector's keys."""

    name: str = key(
        Text(),
        "the `COLLECTORS` entry, chosen with `collector=<name>` (default `single`), who steps "
        "the online env (the offline phase does not read it): `single`: TorchRL's `Collector` "
        "in this process; `multi_sync`: `MultiSyncCollector`, `collector.num_workers` "
        "processes, batches stacked; `multi_async`: `MultiAsyncCollector`, first-come batches; "
        "`ray`: `RayCollector`, `collector.num_workers` Ray actors (needs "
        '`pip install "torchrl-dual[ray]"` and `device=cpu`). `critic=calql` takes `single` '
        "with `collector.num_envs=1` only (its Monte-Carlo labels hold one stream of "
        "transitions until its episode ends) "
        "([Parallel collection](recipe.md#parallel-collection-collector))",
    )
    device: Any = key(
        Maybe(Text()),
        "torch device (`cpu`, `cuda[:N]`) of the acting policy and the collected batches; "
        "`null`: the run's `device`. `device=cuda collector.device=cpu` updates on the GPU and "
        "acts on the CPU, the collector acting with its own copy of the policy, refreshed after "
        "every block of updates "
        "([Parallel collection](recipe.md#parallel-collection-collector)); `collector=ray` "
        "takes `null` or `cpu` only (its actors act on the CPUs of the Ray nodes). May change "
        "on resume",
    )


@dataclass
class SingleCollectorSettings(CollectorSettings):
    """``collector/single.yaml``: the run's own process, ``num_envs`` envs as one batch."""

    num_envs: int = key(
        Integer(1),
        "envs stepped as one batch in this process, the exploration policy acting for all of "
        "them in one call ([Batched envs](recipe.md#parallel-collection-collector)); "
        "`budget.frames_per_batch` counts env steps over all envs and must be a multiple of it; "
        "`1`: the run's env itself (the only value `critic=calql` takes)",
    )


@dataclass
class MultiCollectorSettings(CollectorSettings):
    """``collector/multi_sync.yaml`` and ``collector/multi_async.yaml``."""

    num_workers: int = key(
        Integer(1),
        "worker processes, each stepping its own env; `multi_sync` needs "
        "`budget.frames_per_batch` to be a multiple of it",
    )


@dataclass
class RayCollectorSettings(CollectorSettings):
    """``collector/ray.yaml`` (:mod:`torchrl_dual.recipe.o2o.ray_collector`)."""

    num_workers: int = key(
        Integer(1),
        "remote collectors (Ray actors of one CPU, on any node of the cluster), each stepping "
        "its own env with its own copy of the exploration policy; with `sync: true`, "
        "`budget.frames_per_batch` must be a multiple of it",
    )
    sync: bool = key(
        Flag(),
        "`true`: each actor collects `budget.frames_per_batch / num_workers` frames and the run "
        "gets them stacked (as `multi_sync`); `false`: whichever actor's "
        "`budget.frames_per_batch` frames are ready first (as `multi_async`)",
    )
    address: Any = key(
        Maybe(Text()),
        "`null`: the cluster in `RAY_ADDRESS`, else the one `ray start` runs on this machine, "
        "else a new local Ray runtime on this machine's cores; a string: that cluster (`auto`: "
        "a running one or an error, `<head-ip>:6379`, `ray://<head-ip>:10001`; `local`: always "
        "a new local runtime)",
    )


def check_single(cfg: DictConfig) -> None:
    """``collector=single``: ``collector.num_envs > 1`` envs collect equal shares of a batch."""
    envs = cfg.collector.num_envs
    if envs > 1:
        split = f"collector.num_envs={envs} envs collect equal shares of each batch"
        check_streams(cfg, split, envs, "collector.num_envs", envs, "collector.num_envs=1")


def check_workers(cfg: DictConfig, stacked_by: str | None) -> None:
    """The worker collectors' checks.

    ``stacked_by`` names the keys that split each batch evenly over the workers
    (``None``: the first worker's batch is taken whole).
    """
    workers = cfg.collector.num_workers
    split = None if stacked_by is None else (
        f"{stacked_by} splits each batch over collector.num_workers={workers}"
    )  # fmt: skip
    check_streams(cfg, split, workers, "collector", cfg.collector.name, "collector=single")


def check_streams(
    cfg: DictConfig, split: str | None, parts: int, key: str, value: Any, one_stream: str
) -> None:
    """Checks the online batches from several streams (workers or envs, ``key=value``).

    An even ``split`` into ``parts`` (``None``: not split) needs
    ``budget.frames_per_batch`` to be a multiple of them, and a critic's Monte-Carlo
    labels (Cal-QL's) need ``one_stream``.
    """
    if split is not None and cfg.budget.frames_per_batch % parts:
        raise ConfigError(
            "budget.frames_per_batch", cfg.budget.frames_per_batch, f"{split}: use a multiple of it"
        )
    if CRITICS[cfg.critic.name].monte_carlo_labels:
        raise ConfigError(
            key,
            value,
            f"critic={cfg.critic.name} labels one stream of online episodes with Monte-Carlo "
            f"returns; use {one_stream} with it",
        )


INSTALL_RAY = 'pip install "torchrl-dual[ray]"'


def ray_installed() -> bool:
    """Whether Ray can be imported (without importing it)."""
    return importlib.util.find_spec("ray") is not None


def check_ray_collector(cfg: DictConfig) -> None:
    """What ``collector=ray`` needs: Ray, ``device=cpu``, then the worker collectors' checks.

    Stacked batches (``collector.sync=true``) are split evenly over the actors, as
    ``multi_sync``'s; first-come ones are taken whole, as ``multi_async``'s.
    """
    if not ray_installed():
        raise ConfigError("collector", "ray", f"needs Ray, which is not installed: {INSTALL_RAY}")
    if cfg.device != "cpu":
        raise ConfigError(
            "device",
            cfg.device,
            "collector=ray's remote collectors act on the CPUs of the Ray nodes: use "
            "device=cpu with it, or collector=multi_sync / multi_async on this machine",
        )
    if cfg.collector.device not in (None, "cpu"):
        raise ConfigError(
            "collector.device",
            cfg.collector.device,
            "collector=ray's remote collectors act on the CPUs of the Ray nodes: use null or cpu",
        )
    check_workers(cfg, "collector=ray collector.sync=true" if cfg.collector.sync else None)


class CollectorKind(NamedTuple):
    """One ``collector.name``: its schema and checks, how the run builds it, how weights reach it."""

    settings: type
    """The dataclass of ``collector.*`` (checked by ``validate_config``)."""
    make: Callable[..., Any]
    """``(run, total_frames) -> collector``, acting with the learner's exploration policy."""
    push: Callable[..., None]
    """``(collector, policy) -> None``, after every update block: the policy's current
    parameters and buffers reach the collector's next batch."""
    check: Callable[[DictConfig], None]
    """``cfg -> None``: the combinations of ``collector.*`` with other keys that cannot work
    (``validate_config`` runs it after the key checks)."""
    misplaced: dict[str, str]
    """Another kind's ``collector.*`` key -> why it is not this kind's (``validate_config``
    says so before the key checks, which would only call it unknown)."""


_COLLECTORS = "torchrl_dual.recipe.o2o.collectors"
_RAY = "torchrl_dual.recipe.o2o.ray_collector"

_IN_PROCESS = {
    "num_workers": "collects in this process; choose collector=multi_sync or "
    "collector=multi_async for worker processes, collector=ray for Ray actors"
}
_ONE_ENV_PER_WORKER = {
    "num_envs": "steps one env per worker; batched envs are collector=single's "
    "(collector=single collector.num_envs=N), or raise collector.num_workers"
}

COLLECTORS: dict[str, CollectorKind] = {
    "single": CollectorKind(
        SingleCollectorSettings,
        Ref(f"{_COLLECTORS}:make_single"),
        Ref(f"{_COLLECTORS}:push_to_single"),
        check_single,
        _IN_PROCESS,
    ),
    "multi_sync": CollectorKind(
        MultiCollectorSettings,
        Ref(f"{_COLLECTORS}:make_multi_sync"),
        Ref(f"{_COLLECTORS}:push_to_processes"),
        partial(check_workers, stacked_by="collector=multi_sync"),
        _ONE_ENV_PER_WORKER,
    ),
    "multi_async": CollectorKind(
        MultiCollectorSettings,
        Ref(f"{_COLLECTORS}:make_multi_async"),
        Ref(f"{_COLLECTORS}:push_to_processes"),
        partial(check_workers, stacked_by=None),
        _ONE_ENV_PER_WORKER,
    ),
    "ray": CollectorKind(
        RayCollectorSettings,
        Ref(f"{_RAY}:make_ray"),
        Ref(f"{_RAY}:push_to_actors"),
        check_ray_collector,
        _ONE_ENV_PER_WORKER,
    ),
}
"""``collector.name`` -> its :class:`CollectorKind`."""


def check_output_dir(output_dir: str, resume: bool) -> None:
    """Checks that ``output_dir`` is writable and holds no checkpoint a fresh run would overwrite.

    ``output_dir`` must be a directory (or not exist yet) that this process can create
    and write, and hold no checkpoint unless ``resume=true``: a fresh run never
    overwrites another run's checkpoint. Writability is probed with a temporary folder
    in the nearest existing ancestor (removed at once), so a failed check leaves nothing
    behind.
    """
    value, output_dir = output_dir, Path(output_dir)
    for path in (output_dir, *output_dir.parents):
        if path.exists() and not path.is_dir():
            raise ConfigError("output_dir", value, f"{path} is a file, not a directory")
    existing = next(p for p in (output_dir, *output_dir.parents) if p.exists())
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".write-probe-", dir=existing))
    except OSError as err:
        raise ConfigError(
            "output_dir",
            value,
            f"cannot be created or written in {existing} ({err.strerror}); choose a "
            "directory you can write to",
        ) from None
    checkpoint = output_dir / "checkpoint.pt"
    if checkpoint.exists() and not resume:
        raise ConfigError(
            "resume",
            False,
            f"{checkpoint} exists: pass resume=true to continue that run, or choose "
            "another output_dir (or delete it) to start afresh",
        )
