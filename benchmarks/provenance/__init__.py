"""Where a result was measured: the one helper every JSON under ``benchmarks/results`` is
written through.

:func:`provenance` is ``{"host", "cpu", "commit", "dirty", "date"}``:

* ``host``: 16 hex digits of SHA-256 over ``/etc/machine-id`` (else the hostname and the
  MAC address :func:`uuid.getnode` reads) and the CPU model, salted with this project's
  name. The same machine gives the same id run after run; nothing personal can be read
  back from it. A VM image moved to another CPU gets another id; two VMs cloned from one
  image onto the same CPU model share one (machine-id is copied with the image).
* ``cpu``: the CPU model (``/proc/cpuinfo``), else :func:`platform.processor`.
* ``commit``: the checked-out commit (12 hex digits), ``"?"`` outside a git checkout.
* ``dirty``: whether a tracked file that can change a result differs from that commit
  (everything but ``benchmarks/results/``, ``docs/`` and Markdown files, which the
  benchmarks themselves rewrite); untracked files are not counted.
* ``date``: UTC, to the minute.

:func:`write_json` adds it to a payload (a dict gets a ``"provenance"`` key, a list becomes
``{"rows": [...], "provenance": ...}``) and writes the file. Two results compare cleanly
only when ``host`` and ``commit`` agree and neither is dirty (:func:`crossing`).

    >>> sorted(provenance())
    ['commit', 'cpu', 'date', 'dirty', 'host']
    >>> len(host_id()) == 16 and host_id() == host_id()
    True
"""

from __future__ import annotations

import hashlib
import json
import platform
import socket
import subprocess
import uuid
from collections.abc import Iterable
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[2]
_SALT = "torchrl-dual host id\n"
_NOT_CODE = (":(exclude)benchmarks/results", ":(exclude)docs", ":(exclude,glob)**/*.md")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`;
    ``""`` when unknown)."""
    try:
        with open("/proc/cpuinfo") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor()


def host_id() -> str:
    """A stable, anonymous id of this machine (see the module docstring)."""
    for path in ("/etc/machine-id", "/var/lib/dbus/machine-id"):
        try:
            machine = Path(path).read_text().strip()
        except OSError:
            continue
        if machine:
            break
    else:
        machine = f"{socket.gethostname()}/{uuid.getnode():012x}"
    digest = hashlib.sha256(f"{_SALT}{machine}\n{cpu_model()}".encode())
    return digest.hexdigest()[:16]


def _git(tree: Path, *args: str) -> str | None:
    try:
        proc = subprocess.run(
            ["git", "-C", str(tree), *args], capture_output=True, text=True, timeout=30
        )
    except (OSError, subprocess.TimeoutExpired):
        return None
    return proc.stdout.strip() if proc.returncode == 0 else None


def provenance(tree: Path | str = REPO) -> dict[str, Any]:
    """``{"host", "cpu", "commit", "dirty", "date"}`` of this machine and of the source
    tree ``tree`` (default: this repository)."""
    commit = _git(Path(tree), "rev-parse", "--short=12", "HEAD")
    status = _git(
        Path(tree), "status", "--porcelain", "--untracked-files=no", "--", ".", *_NOT_CODE
    )
    return {
        "host": host_id(),
        "cpu": cpu_model(),
        "commit": commit or "?",
        "dirty": None if status is None else bool(status),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
    }


def with_provenance(payload: Any, record: dict[str, Any] | None = None) -> dict[str, Any]:
    """``payload`` with its provenance (``record``, default :func:`provenance`): a dict
    gets the key ``"provenance"``, anything else becomes ``{"rows": payload, ...}``.

    Examples:
        >>> with_provenance({"a": 1}, {"host": "h"})
        {'a': 1, 'provenance': {'host': 'h'}}
        >>> with_provenance([1, 2], {"host": "h"})
        {'rows': [1, 2], 'provenance': {'host': 'h'}}
    """
    record = provenance() if record is None else record
    if isinstance(payload, dict):
        return {**payload, "provenance": record}
    return {"rows": payload, "provenance": record}


def write_json(
    path: Path | str, payload: Any, *, indent: int = 1, tree: Path | str = REPO, **dump: Any
) -> dict:
    """Writes :func:`with_provenance` of ``payload`` (the commit of ``tree``, the source tree
    that made it) to ``path`` with a trailing newline; returns what it wrote."""
    stamped = with_provenance(payload, provenance(tree))
    Path(path).write_text(json.dumps(stamped, indent=indent, **dump) + "\n")
    return stamped


def record_of(result: dict) -> dict[str, Any]:
    """A result's provenance: its ``"provenance"`` entry, else what an older result kept
    (its ``commit``; no host)."""
    if isinstance(result.get("provenance"), dict):
        return result["provenance"]
    return {"host": None, "commit": result.get("commit"), "dirty": None}


def crossing(results: Iterable[dict]) -> str:
    """What ``results`` (e.g. both sides of a pair) do not share: ``""`` when they ran on
    one recorded host and one commit, none dirty; else e.g. ``"2 hosts, 2 commits"``,
    ``"host not recorded"``, ``"dirty tree"``.

    Examples:
        >>> run = lambda host, commit: {"provenance": {"host": host, "commit": commit,
        ...                                            "dirty": False}}
        >>> crossing([run("a", "c1"), run("a", "c1")])
        ''
        >>> crossing([run("a", "c1"), run("b", "c2")])
        '2 hosts, 2 commits'
        >>> crossing([run("a", "c1"), {"commit": "c1"}])
        'host not recorded'
    """
    records = [record_of(r) for r in results]
    hosts = {r.get("host") for r in records}
    commits = {r.get("commit") for r in records}
    notes = []
    if None in hosts:
        notes.append("host not recorded")
    elif len(hosts) > 1:
        notes.append(f"{len(hosts)} hosts")
    if None in commits or "?" in commits:
        notes.append("commit not recorded")
    elif len(commits) > 1:
        notes.append(f"{len(commits)} commits")
    if any(r.get("dirty") for r in records):
        notes.append("dirty tree")
    return ", ".join(notes)
