"""One writer per run directory: the lock a run holds on its ``output_dir``.

Two runs into one directory would write the same checkpoint, logs and ``summary.json``.
A run takes ``<output_dir>/.lock`` before it writes anything (the command line before
Hydra creates the directory, :class:`~torchrl_dual.recipe.O2ORun` before it checks for a
checkpoint), with an exclusive POSIX record lock (``fcntl.lockf``): a second process is
refused with one line naming the directory and the process that runs there. The kernel
releases the lock when its process ends, however it ends, and a forked child (a
collector's worker) does not inherit it, so the file a crashed or killed run leaves
behind (naming a process that is gone) is stale and the next run takes it over. Within
one process the lock is held once, however many times it is asked for; it is released by
the :func:`run_directory_lock` block that took it, or when the process ends.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO

from torchrl_dual.recipe.settings.errors import UserError

LOCK_NAME = ".lock"
_HELD: dict[Path, IO[str]] = {}  # the locks this process holds, by resolved directory


def _owner_text(lock: IO[str]) -> str:
    """The holder a lock file names, as ``process <pid> on <host> (<command>, since <t>)``."""
    try:
        lock.seek(0)
        owner = json.loads(lock.read())
        return (
            f"process {owner['pid']} on {owner['host']} ({owner['command']}, since "
            f"{owner['since']})"
        )
    except (OSError, ValueError, KeyError, TypeError):  # written by a run starting now
        return "another process"


def _shortened(text: str, limit: int = 80) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def acquire_run_directory(output_dir: str | Path) -> bool:
    """Takes the lock of ``output_dir`` (created if need be) for this process.

    Returns whether this call took it (``False``: the process held it already).

    Raises:
        UserError: another live process holds it.
    """
    directory = Path(output_dir).resolve()
    if directory in _HELD:
        return False
    path = directory / LOCK_NAME
    while True:
        try:
            directory.mkdir(parents=True, exist_ok=True)
            lock = open(path, "a+")  # noqa: SIM115 (held open while the run runs)
        except OSError as err:
            raise UserError(
                "output_dir",
                str(output_dir),
                f"cannot create {path} ({err.strerror}); choose a directory you can write to",
            ) from None
        try:
            fcntl.lockf(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except (BlockingIOError, PermissionError):  # EAGAIN or EACCES: held elsewhere
            holder = _owner_text(lock)
            lock.close()
            raise UserError(
                "output_dir",
                str(output_dir),
                f"in use by {holder}; wait for that run to end or choose another output_dir",
            ) from None
        try:  # a run releasing it may have removed the file after we opened it
            same_file = os.stat(path).st_ino == os.fstat(lock.fileno()).st_ino
        except FileNotFoundError:
            same_file = False
        if same_file:
            break
        lock.close()
    lock.seek(0)
    lock.truncate()
    owner = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "command": _shortened(" ".join([Path(sys.argv[0]).name, *sys.argv[1:]])),
        "since": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }
    lock.write(json.dumps(owner))
    lock.flush()
    _HELD[directory] = lock
    return True


def release_run_directory(output_dir: str | Path) -> None:
    """Releases (and removes) the lock of ``output_dir`` if this process holds it."""
    lock = _HELD.pop(Path(output_dir).resolve(), None)
    if lock is not None:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(lock.name)
        lock.close()


@contextlib.contextmanager
def run_directory_lock(output_dir: str | Path) -> Iterator[None]:
    """Holds the lock of ``output_dir`` for the block.

    It is released at the block's end if the block took it; a lock the process held
    before stays held.

    Examples:
        >>> import tempfile
        >>> with tempfile.TemporaryDirectory() as tmp:
        ...     with run_directory_lock(tmp):
        ...         held = (Path(tmp) / LOCK_NAME).exists()
        ...     held, (Path(tmp) / LOCK_NAME).exists()
        (True, False)
    """
    took = acquire_run_directory(output_dir)
    try:
        yield
    finally:
        if took:
            release_run_directory(output_dir)
