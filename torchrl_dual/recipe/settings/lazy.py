"""References to the recipe's builders that import nothing until they are called.

The tables of :mod:`torchrl_dual.recipe.settings` (algorithms, env kits, critics,
replays, collectors) hold each entry's schema and, as a :class:`Ref`, the callable that
builds it. Checking a config therefore imports neither torch nor TorchRL: a bad value
is reported at once, and only the parts a run uses are imported when it starts.
"""

from __future__ import annotations

import importlib
from typing import Any


class Ref:
    """A callable named ``"package.module:attribute"``, imported on first use.

    Calling it calls the attribute; reading another attribute reads it from the target
    (e.g. a learner class's ``online_keys``).

    Args:
        target (str): ``"package.module:attribute"``.

    Examples:
        >>> join = Ref("os.path:join")
        >>> join("a", "b") == __import__("os").path.join("a", "b")
        True
        >>> join
        Ref('os.path:join')
        >>> Ref("os.path:no_such_name").resolve()
        Traceback (most recent call last):
        ...
        AttributeError: os.path has no attribute 'no_such_name' (Ref 'os.path:no_such_name')
    """

    __slots__ = ("target", "_resolved")

    def __init__(self, target: str) -> None:
        if target.count(":") != 1:
            raise ValueError(f"Ref target must be 'module:attribute', got {target!r}")
        self.target = target
        self._resolved: Any = None

    def resolve(self) -> Any:
        """The target object (imported once)."""
        if self._resolved is None:
            module_name, attribute = self.target.split(":")
            module = importlib.import_module(module_name)
            try:
                self._resolved = getattr(module, attribute)
            except AttributeError:
                raise AttributeError(
                    f"{module_name} has no attribute {attribute!r} (Ref {self.target!r})"
                ) from None
        return self._resolved

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        """Calls the target object (imported on first use) with the arguments given."""
        return self.resolve()(*args, **kwargs)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.resolve(), name)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Ref) and other.target == self.target

    def __hash__(self) -> int:
        return hash(self.target)

    def __repr__(self) -> str:
        return f"Ref({self.target!r})"
