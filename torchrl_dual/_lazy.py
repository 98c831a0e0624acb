"""Package attributes imported on first access (PEP 562).

Importing a light submodule (the recipe's config schema) then does not import torch, TorchRL
and the rest.

``from torchrl_dual import LaplaceEnsembleActor`` and ``torchrl_dual.LaplaceEnsembleActor``
behave as with eager imports; only the moment of the import changes.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_exports(
    package: str, exports: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """The ``(__getattr__, __dir__)`` pair of a package whose attributes import lazily.

    ``exports`` maps each public name of ``package`` to the module that defines it.

    Examples:
        >>> getattr_, dir_ = lazy_exports("example", {"join": "os.path"})
        >>> getattr_("join")("a", "b") == __import__("os").path.join("a", "b")
        True
        >>> getattr_("nope")
        Traceback (most recent call last):
        ...
        AttributeError: module 'example' has no attribute 'nope'
    """

    def __getattr__(name: str) -> Any:
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        return getattr(importlib.import_module(module), name)

    def __dir__() -> list[str]:
        return sorted(exports)

    return __getattr__, __dir__
