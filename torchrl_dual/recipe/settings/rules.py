"""Schemas of the recipe's config groups: a dataclass per group, a :class:`Rule` per key.

A schema is a dataclass whose fields are declared with :func:`key`: the field name is the
config key, the :class:`Rule` says what values are allowed and the text says what the
key means. :func:`check_section` checks one composed config group against its schema
and raises :class:`~torchrl_dual.recipe.settings.errors.ConfigError` on the first unknown key,
missing key or bad value, naming the key, the value and what is allowed.

Examples:
    >>> from dataclasses import dataclass
    >>> from omegaconf import OmegaConf
    >>> @dataclass
    ... class Critic:
    ...     expectile: float = key(Real(0, 1, low_open=True, high_open=True), "IQL τ")
    >>> check_section(Critic, OmegaConf.create({"expectile": 1.5}), "critic", ["critic.expectile"])
    Traceback (most recent call last):
    ...
    torchrl_dual.recipe.settings.errors.ConfigError: critic.expectile=1.5: must lie in (0, 1)
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Sequence
from typing import Any, TypeVar

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from torchrl_dual.recipe.settings.errors import ConfigError, unknown_key

S = TypeVar("S")


class Rule:
    """What one config key accepts; :meth:`complaint` is ``None`` for an allowed value."""

    def allows(self, value: Any) -> bool:
        """Whether the key accepts ``value``."""
        raise NotImplementedError

    def describe(self) -> str:
        """What the key accepts, as the end of an error line (``"must be ..."``)."""
        raise NotImplementedError

    def complaint(self, value: Any) -> str | None:
        """``None`` if ``value`` is allowed, else :meth:`describe`'s text."""
        return None if self.allows(value) else self.describe()


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return (_is_int(value) or isinstance(value, float)) and math.isfinite(value)


def _bounds(low: Any, high: Any, low_open: bool, high_open: bool) -> str:
    if high is None:
        return f"{'>' if low_open else '>='} {low}"
    if low is None:
        return f"{'<' if high_open else '<='} {high}"
    return f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"


@dataclasses.dataclass(frozen=True)
class Integer(Rule):
    """An integer (not a bool) in ``[low, high]``; ``None`` leaves a side open."""

    low: int | None = None
    high: int | None = None

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is an integer (not a bool) in ``[low, high]``."""
        return (
            _is_int(value)
            and (self.low is None or value >= self.low)
            and (self.high is None or value <= self.high)
        )

    def describe(self) -> str:
        """``"must be an integer"``, with its bounds."""
        if self.low is None and self.high is None:
            return "must be an integer"
        if self.high is None:
            return f"must be an integer >= {self.low}"
        return f"must be an integer in {_bounds(self.low, self.high, False, False)}"


@dataclasses.dataclass(frozen=True)
class PowerOfTwo(Rule):
    """An integer ``2^k``, ``k >= 0`` (e.g. sampling steps that distillation halves to 1)."""

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is an integer power of 2."""
        return _is_int(value) and value >= 1 and value & (value - 1) == 0

    def describe(self) -> str:
        """``"must be a power of 2 (1, 2, 4, 8, ...)"``."""
        return "must be a power of 2 (1, 2, 4, 8, ...)"


@dataclasses.dataclass(frozen=True)
class Real(Rule):
    """A finite number between ``low`` and ``high`` (open or closed ends)."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a number within the bounds (each open or closed)."""
        if not _is_number(value):
            return False
        low_ok = self.low is None or (value > self.low if self.low_open else value >= self.low)
        high_ok = self.high is None or (value < self.high if self.high_open else value <= self.high)
        return low_ok and high_ok

    def describe(self) -> str:
        """``"must lie in <bounds>"`` (or ``"must be a finite number"`` without bounds)."""
        if self.low is None and self.high is None:
            return "must be a finite number"
        bounds = _bounds(self.low, self.high, self.low_open, self.high_open)
        if self.low is not None and self.high is not None:
            return f"must lie in {bounds}"
        return f"must be a number {bounds}"


@dataclasses.dataclass(frozen=True)
class Choice(Rule):
    """One of a fixed set of strings (a library's table of names, e.g. ``WEIGHTINGS``)."""

    options: Sequence[str]

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is one of ``options``."""
        return isinstance(value, str) and value in self.options

    def describe(self) -> str:
        """``"unknown option; choose one of <options>"``."""
        return "unknown option; choose one of " + ", ".join(self.options)


@dataclasses.dataclass(frozen=True)
class Flag(Rule):
    """A boolean, ``true`` or ``false``."""

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a bool."""
        return isinstance(value, bool)

    def describe(self) -> str:
        """``"must be true or false"``."""
        return "must be true or false"


@dataclasses.dataclass(frozen=True)
class Text(Rule):
    """A non-empty string."""

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a non-empty string."""
        return isinstance(value, str) and value != ""

    def describe(self) -> str:
        """``"must be a non-empty string"``."""
        return "must be a non-empty string"


@dataclasses.dataclass(frozen=True)
class Maybe(Rule):
    """``null`` or what ``rule`` allows."""

    rule: Rule

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is ``None`` or allowed by ``rule``."""
        return value is None or self.rule.allows(value)

    def describe(self) -> str:
        """``must be null or <the rule's text>``; for a :class:`Choice`, its options.

        Examples:
            >>> Maybe(Integer(0)).describe()
            'must be null or an integer >= 0'
            >>> Maybe(Choice(("default", "max-autotune"))).describe()
            'unknown option; choose null or one of default, max-autotune'
        """
        if isinstance(self.rule, Choice):  # "unknown option; ...", not a "must be" text
            return "unknown option; choose null or one of " + ", ".join(self.rule.options)
        return "must be null or " + self.rule.describe().removeprefix("must be ")


@dataclasses.dataclass(frozen=True)
class Either(Rule):
    """What any of ``rules`` allows (e.g. ``"evidence"`` or a number > 0)."""

    rules: tuple[Rule, ...]
    text: str

    def allows(self, value: Any) -> bool:
        """Whether any of ``rules`` allows ``value``."""
        return any(rule.allows(value) for rule in self.rules)

    def describe(self) -> str:
        """``text``."""
        return self.text


@dataclasses.dataclass(frozen=True)
class IntegerList(Rule):
    """A list of integers ``>= low`` (its length is a cross-key check)."""

    low: int = 0

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a list of integers ``>= low``."""
        return isinstance(value, list) and all(Integer(self.low).allows(v) for v in value)

    def describe(self) -> str:
        """``"must be a list of integers >= <low>"``."""
        return f"must be a list of integers >= {self.low}"


@dataclasses.dataclass(frozen=True)
class CellList(Rule):
    """A list of grid cells ``[row, col]`` (integers ``>= 0``).

    Whether each is open is a cross-key check against the layout.
    """

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a list of ``[row, col]`` pairs of integers ``>= 0``."""
        return isinstance(value, list) and all(
            isinstance(cell, list) and len(cell) == 2 and IntegerList(0).allows(cell)
            for cell in value
        )

    def describe(self) -> str:
        """``"must be a list of [row, col] cells, e.g. [[3, 1]]"``."""
        return "must be a list of [row, col] cells, e.g. [[3, 1]]"


@dataclasses.dataclass(frozen=True)
class RealList(Rule):
    """A list of ``length`` finite numbers (e.g. a pair of reference returns)."""

    length: int

    def allows(self, value: Any) -> bool:
        """Whether ``value`` is a list of ``length`` numbers (not bools)."""
        return (
            isinstance(value, list)
            and len(value) == self.length
            and all(_is_number(v) and not isinstance(v, bool) for v in value)
        )

    def describe(self) -> str:
        """``"must be a list of <length> finite numbers"``."""
        return f"must be a list of {self.length} finite numbers"


def key(rule: Rule, doc: str = "") -> Any:
    """Declares a schema field: the config key's :class:`Rule` and its meaning."""
    return dataclasses.field(metadata={"rule": rule, "doc": doc})


def dotted_keys(schema: type, prefix: str) -> list[str]:
    """Every key of ``schema`` as ``prefix.name``."""
    return [f"{prefix}.{f.name}" if prefix else f.name for f in dataclasses.fields(schema)]


def as_settings(schema: type[S], node: DictConfig) -> S:
    """The config group ``node`` as an instance of ``schema``.

    ``node`` has passed :func:`check_section` against ``schema`` (``validate_config``);
    the instance holds plain Python values, interpolations resolved, sub-groups left
    out. Builders take these typed sections, not the config.

    Examples:
        >>> from omegaconf import OmegaConf
        >>> from torchrl_dual.recipe.settings.schema import CompileSettings
        >>> node = OmegaConf.create(
        ...     {"compile": True, "compile_mode": "${mode}", "cudagraphs": False, "mode": None}
        ... )
        >>> as_settings(CompileSettings, node)
        CompileSettings(compile=True, compile_mode=None, cudagraphs=False)
    """
    values = {f.name: read_value(node, f.name, f.name) for f in dataclasses.fields(schema)}
    return schema(**values)


def read_value(node: DictConfig, name: str, dotted: str) -> Any:
    """``node[name]`` as a plain Python value, interpolations resolved."""
    try:
        value = node[name]
    except OmegaConfBaseException as err:  # missing value (???) or a broken interpolation
        raw = OmegaConf.to_container(node, resolve=False).get(name)
        reason = str(err).splitlines()[0]
        raise ConfigError(dotted, raw, f"cannot be read ({reason})") from err
    if isinstance(value, DictConfig | ListConfig):
        return OmegaConf.to_container(value, resolve=True)
    return value


def check_section(
    schema: type, node: Any, prefix: str, known: Iterable[str], skip: Iterable[str] = ()
) -> None:
    """Checks the config group ``node`` (at ``prefix``) against ``schema``.

    Args:
        schema (type): the group's dataclass of :func:`key` fields.
        node (DictConfig): the composed group.
        prefix (str): its dotted path (``""`` for the top level).
        known (iterable of str): every valid dotted key, for "did you mean" hints.
        skip (iterable of str): keys of ``node`` that other schemas check (sub-groups).
    """
    where = prefix or "the config"
    if not isinstance(node, DictConfig):
        raise ConfigError(prefix or None, node, "must be a group of keys")
    fields = {f.name: f for f in dataclasses.fields(schema)}
    skip = set(skip)
    for name in node.keys():
        if name not in fields and name not in skip:
            raise unknown_key(f"{prefix}.{name}" if prefix else str(name), known)
    for name, field in fields.items():
        dotted = f"{prefix}.{name}" if prefix else name
        if name not in node:
            raise ConfigError(None, None, f"missing key '{dotted}' in {where}")
        value = read_value(node, name, dotted)
        complaint = field.metadata["rule"].complaint(value)
        if complaint is not None:
            raise ConfigError(dotted, value, complaint)
