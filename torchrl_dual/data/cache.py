"""On-disk cache of generated offline data sets (memmapped TensorDict + JSON metadata).

A cache entry is a directory::

    <path>/transitions/   TensorDict.memmap(...) of the transitions
    <path>/meta.json      {"spec": ..., "reference_min": ..., "reference_max": ..., "metadata": ...}

It is written into a hidden sibling temporary directory and renamed into place only
once complete, so an interrupted run never leaves a loadable half-written entry. An
entry whose ``spec`` differs from the requested one (other seed, size, generator
version...) is regenerated.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tensordict import TensorDict

from torchrl_dual.data.offline_dataset import OfflineDataset

CACHE_FORMAT_VERSION = 1
_META = "meta.json"
_TD = "transitions"
_STALE_SECONDS = 3600.0

logger = logging.getLogger(__name__)


def default_cache_dir() -> Path:
    """Root of the data-set cache: ``$TORCHRL_DUAL_CACHE`` or ``~/.cache/torchrl_dual``.

    Examples:
        >>> isinstance(default_cache_dir(), Path)
        True
    """
    return Path(os.environ.get("TORCHRL_DUAL_CACHE", Path.home() / ".cache" / "torchrl_dual"))


def _normalize(spec: dict[str, Any]) -> dict[str, Any]:
    return json.loads(json.dumps(spec, sort_keys=True))


def load_cached_dataset(path: str | Path, spec: dict[str, Any]) -> OfflineDataset | None:
    """Loads a cache entry if it is complete and was made for ``spec``; else ``None``.

    The transitions are copied into memory, so editing them never alters the cache.

    Args:
        path (str or Path): the entry directory.
        spec (dict): the identity the entry must have been made for (see
            :func:`load_or_generate`).

    Returns:
        OfflineDataset or None: the data set, or ``None`` when the entry is missing,
        incomplete, unreadable, of another format or made for another ``spec``.

    Examples:
        >>> import tempfile
        >>> load_cached_dataset(Path(tempfile.mkdtemp()) / "missing", {"seed": 0}) is None
        True
    """
    path = Path(path)
    meta_file = path / _META
    if not meta_file.is_file():
        return None
    try:
        meta = json.loads(meta_file.read_text())
    except (OSError, json.JSONDecodeError) as err:
        logger.warning("Ignoring unreadable cache metadata %s (%s).", meta_file, err)
        return None
    if meta.get("format_version") != CACHE_FORMAT_VERSION or not meta.get("complete"):
        return None
    if meta.get("spec") != _normalize(spec):
        logger.info("Cache %s was made for %s, not %s: regenerating.", path, meta.get("spec"), spec)
        return None
    try:
        transitions = TensorDict.load_memmap(path / _TD).clone()
    except Exception as err:  # a corrupted entry is a cache miss
        logger.warning("Ignoring unreadable cache %s (%s).", path, err)
        return None
    return OfflineDataset(
        transitions,
        reference_min=meta.get("reference_min"),
        reference_max=meta.get("reference_max"),
        metadata=meta.get("metadata", {}),
    )


def _remove_stale_siblings(path: Path) -> None:
    now = time.time()
    for sibling in path.parent.glob(f".{path.name}.*"):
        try:
            if now - sibling.stat().st_mtime > _STALE_SECONDS:
                shutil.rmtree(sibling, ignore_errors=True)
        except OSError:
            pass


def save_cached_dataset(path: str | Path, spec: dict[str, Any], data: OfflineDataset) -> Path:
    """Writes ``data`` atomically to ``path`` (replacing any previous entry).

    Args:
        path (str or Path): the entry directory.
        spec (dict): JSON-serializable description that a later load must match.
        data (OfflineDataset): transitions, references and metadata (JSON-serializable).

    Examples:
        >>> import tempfile, numpy as np
        >>> from torchrl_dual.data import make_transitions
        >>> td = make_transitions(np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((2, 1)),
        ...     np.zeros(2), np.zeros(2, bool), np.ones(2, bool), np.arange(2))
        >>> root = Path(tempfile.mkdtemp())
        >>> _ = save_cached_dataset(root / "toy", {"v": 1}, OfflineDataset(td, 0.0, 1.0))
        >>> len(load_cached_dataset(root / "toy", {"v": 1})), load_cached_dataset(root / "toy", {"v": 2})
        (2, None)
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_siblings(path)
    tmp = path.parent / f".{path.name}.tmp-{uuid.uuid4().hex}"
    tmp.mkdir()
    try:
        data.transitions.memmap(tmp / _TD)
        meta = {
            "format_version": CACHE_FORMAT_VERSION,
            "spec": _normalize(spec),
            "reference_min": data.reference_min,
            "reference_max": data.reference_max,
            "metadata": _normalize(data.metadata),
            "num_transitions": len(data),
            "created": time.strftime("%Y-%m-%dT%H:%M:%S"),
            "complete": True,
        }
        with open(tmp / _META, "w") as f:
            json.dump(meta, f, indent=2, sort_keys=True)
            f.flush()
            os.fsync(f.fileno())
        old = None
        if path.exists():
            old = path.parent / f".{path.name}.old-{uuid.uuid4().hex}"
            os.rename(path, old)
        os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return path


def load_or_generate(
    path: str | Path,
    spec: dict[str, Any],
    generate: Callable[[], OfflineDataset],
) -> OfflineDataset:
    """Returns the cached data set for ``spec`` at ``path``, generating and caching it if needed.

    Args:
        path (str or Path): the entry directory.
        spec (dict): JSON-serializable identity of the data (generator name and version,
            every generation parameter, seed).
        generate (callable): builds the :class:`OfflineDataset` on a cache miss.

    Examples:
        >>> import tempfile, numpy as np
        >>> from torchrl_dual.data import make_transitions
        >>> def make():
        ...     td = make_transitions(np.zeros((3, 1)), np.zeros((3, 1)), np.zeros((3, 1)),
        ...         np.zeros(3), np.zeros(3, bool), np.ones(3, bool), np.arange(3))
        ...     return OfflineDataset(td, 0.0, 1.0, {"source": "toy"})
        >>> path = Path(tempfile.mkdtemp()) / "toy"
        >>> load_or_generate(path, {"n": 3}, make).metadata
        {'source': 'toy'}
    """
    cached = load_cached_dataset(path, spec)
    if cached is not None:
        return cached
    data = generate()
    save_cached_dataset(path, spec, data)
    loaded = load_cached_dataset(path, spec)
    return loaded if loaded is not None else data
