"""The recipe's one path for mistakes a user can fix: one ``error:`` line and exit code 2.

A bad config value, an unknown key, an impossible combination, a device that is not
there, bad offline data or an unusable checkpoint is a :class:`UserError` (its
subclass :class:`ConfigError` for what is found before anything runs). The command
line reports it with :func:`user_errors`: one line on stderr naming the key, the value
given and what is allowed, and exit code 2. ``debug=true`` or ``HYDRA_FULL_ERROR=1``
also prints the traceback. Every other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from difflib import get_close_matches
from typing import Any, NoReturn

EXIT_CODE = 2
"""Exit status of a run stopped by a :class:`UserError` (``argparse`` uses 2 too)."""


def format_value(value: Any) -> str:
    """A config value as the user would type it on the command line.

    Examples:
        >>> format_value(None), format_value(True), format_value([10, 10]), format_value("cpu")
        ('null', 'true', '[10, 10]', 'cpu')
    """
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return "[" + ", ".join(format_value(v) for v in value) + "]"
    return str(value)


class UserError(ValueError):
    r"""A mistake the user can fix, reported as ``<key>=<value>: <problem>`` on one line.

    Args:
        key (str, optional): the dotted config key at fault (``None`` when none is).
        value: the value the user gave for ``key``.
        problem (str): what is wrong and what is allowed, e.g. ``"must be an integer >= 0"``.

    Examples:
        >>> str(UserError("budget.online_frames", -5, "must be an integer >= 0"))
        'budget.online_frames=-5: must be an integer >= 0'
        >>> str(UserError(None, None, "two\nlines"))
        'two lines'
    """

    def __init__(self, key: str | None, value: Any, problem: str) -> None:
        self.key, self.value, self.problem = key, value, problem
        subject = "" if key is None else f"{key}={format_value(value)}: "
        super().__init__(" ".join(f"{subject}{problem}".split()))


class ConfigError(UserError):
    """A :class:`UserError` found in the composed config, before any data or network.

    Examples:
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked
        >>> try:
        ...     compose_checked(CONFIG_DIR, ["budget.online_frames=-5"])
        ... except ConfigError as error:
        ...     print(error, "|", error.key, error.value)
        budget.online_frames=-5: must be an integer >= 0 | budget.online_frames -5
    """


def unknown_key(key: str, known: Iterable[str], owners: Sequence[str] = ()) -> ConfigError:
    """The error for a key no schema has, with a hint.

    With ``owners`` (the ``group=option`` choices that do have it) the hint says which
    choice brings the key; else it names the closest known key of the same depth.

    Examples:
        >>> str(unknown_key("budget.onlin_frames", ["budget.online_frames", "seed"]))
        "unknown key 'budget.onlin_frames'; did you mean budget.online_frames?"
        >>> str(unknown_key("critic.bellman_loss", [], owners=["critic=calql"]))
        "unknown key 'critic.bellman_loss' in this config; it is a key of critic=calql: choose it, or leave the key out"
    """
    if owners:
        return ConfigError(
            None,
            None,
            f"unknown key '{key}' in this config; it is a key of {' or '.join(owners)}: "
            f"choose {'it' if len(owners) == 1 else 'one'}, or leave the key out",
        )
    depth = key.count(".")
    close = get_close_matches(key, [k for k in known if k.count(".") == depth], n=1, cutoff=0.6)
    hint = f"; did you mean {close[0]}?" if close else ""
    return ConfigError(None, None, f"unknown key '{key}'{hint}")


def debug_requested(debug: bool = False) -> bool:
    """Whether the user asked for tracebacks (``debug=true`` or ``HYDRA_FULL_ERROR=1``)."""
    return bool(debug) or os.environ.get("HYDRA_FULL_ERROR") == "1"


def report(err: UserError, *, debug: bool = False) -> NoReturn:
    """Prints ``error: <err>`` (after the traceback if asked for) and exits with 2."""
    sys.stdout.flush()
    if debug_requested(debug):
        traceback.print_exception(type(err), err, err.__traceback__, file=sys.stderr)
    print(f"error: {err}", file=sys.stderr, flush=True)
    sys.exit(EXIT_CODE)


def warn(text: str) -> None:
    """Prints ``warning: <text>`` on one line of stderr; the run goes on.

    Something the run can do, but probably not what the user meant.
    """
    sys.stdout.flush()
    print("warning: " + " ".join(text.split()), file=sys.stderr, flush=True)


@contextmanager
def user_errors(*, debug: bool = False) -> Iterator[None]:
    """Turns a :class:`UserError` raised inside the block into :func:`report`.

    Args:
        debug (bool): print the traceback before the ``error:`` line (also with
            ``HYDRA_FULL_ERROR=1``).

    Examples:
        >>> with user_errors():
        ...     pass  # no UserError: the block runs as it is
    """
    try:
        yield
    except UserError as err:
        report(err, debug=debug)
