"""Ctrl-C and SIGTERM in a recipe run: both stop it as a ``KeyboardInterrupt``.

Either stops the run at a point where its state is whole.

:func:`signals_as_interrupts` (entered by :func:`~torchrl_dual.recipe.run_o2o` for the
whole run) makes SIGTERM, what a cluster scheduler or ``kill`` sends before it kills a
job, raise ``KeyboardInterrupt`` as Ctrl-C (SIGINT) does, so that both end the run the
same way: a checkpoint, one line, ``resume=true`` continues. Inside :func:`held` (an
offline stage's update loop, the processing of one online batch) a signal is only noted:
the loop asks :func:`requested` after each update and stops there, with a checkpoint of
that update, and the block raises a noted signal when it ends. Anywhere else the signal
raises at once, and the run's last checkpoint is what a resume continues from.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager

_DEFAULT_HANDLERS = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
"""The handlers :func:`signals_as_interrupts` replaces: Python's own; a signal that is
ignored (``SIG_IGN``, e.g. SIGINT of a background job) or has its owner's handler keeps it."""


class _State:
    holding = 0  # depth of held() blocks
    noted: signal.Signals | None = None  # a signal received inside one


_state = _State()


def _interrupt(signum: int, frame: object) -> None:
    if _state.holding:
        _state.noted = signal.Signals(signum)
        return
    raise KeyboardInterrupt(signal.Signals(signum).name)


@contextmanager
def signals_as_interrupts() -> Iterator[None]:
    """Within the block, SIGINT and SIGTERM raise ``KeyboardInterrupt``.

    They are held back inside :func:`held`; the previous handlers come back at its end.
    Signal handlers belong to the main thread: in another thread the block changes
    nothing.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    replaced = {
        signum: signal.signal(signum, _interrupt)
        for signum, default in _DEFAULT_HANDLERS.items()
        if signal.getsignal(signum) is default
    }
    try:
        yield
    finally:
        for signum, previous in replaced.items():
            signal.signal(signum, previous)
        _state.noted = None


@contextmanager
def held() -> Iterator[None]:
    """Within the block a signal only sets :func:`requested`; it is raised when the block ends.

    If no one took it, the block raises ``KeyboardInterrupt`` when it ends (not when it
    ends in an exception).
    """
    _state.holding += 1
    try:
        yield
    finally:
        _state.holding -= 1
        noted = None
        if not _state.holding:
            noted, _state.noted = _state.noted, None
    if noted is not None:
        raise KeyboardInterrupt(noted.name)


def requested() -> bool:
    """Whether a signal came during :func:`held`; taking it, the caller stops now."""
    noted, _state.noted = _state.noted, None
    return noted is not None
