"""The recipe's key tables, generated from its schemas: ``docs/config.md``.

Each config key is described once, by the ``doc`` of its :func:`~.rules.key` field; this
module prints, for every schema a config group can select, a Markdown table of its keys:
the default of each shipped YAML file that sets the key, what the key's
:class:`~.rules.Rule` accepts and what it means. ``tests/test_config_reference.py`` fails
when ``docs/config.md`` differs from what :func:`key_reference` prints; rewrite it with
``python -m torchrl_dual.recipe.settings.key_tables docs/config.md``.

Examples:
    >>> from torchrl_dual.recipe.settings.schema import CompileSettings
    >>> print(key_table(CompileSettings, {"config.yaml": {"compile": False}})[2][:39])
    | `compile` | `false` | true or false |
"""

from __future__ import annotations

import dataclasses
import re
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import yaml

from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.envs import ENV_KITS
from torchrl_dual.recipe.settings.loggers import LOGGERS
from torchrl_dual.recipe.settings.o2o import COLLECTORS, REPLAYS
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.recipe.settings.schema import BudgetSettings, CompileSettings, RunSettings

CONFIG_DIR = Path(__file__).resolve().parents[1] / "config"
"""The shipped config tree (``torchrl_dual/recipe/config``)."""

_GROUPS = ("budget", "env", "algo", "critic", "replay", "collector", "logger")
"""The config groups, in the order of the page (an algorithm's sections come in
:data:`_SECTIONS`'s order)."""

_SECTIONS = (
    *("", "compile", "budget", "env", "planner", "distillation", "actor", "laplace"),
    *("exploration", "augment", "online", "critic", "replay", "collector", "logger"),
)
"""The sections in the order of the page; any other follows as it is found."""


def _load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text(encoding="utf-8")) or {}


def _options(group: str) -> Iterator[tuple[str, dict[str, Any]]]:
    """``(name, mapping)`` of every YAML file of ``group``, by name."""
    for path in sorted((CONFIG_DIR / group).glob("*.yaml")):
        yield path.stem, _load(path)


def selections() -> dict[tuple[str, type], dict[str, dict[str, Any]]]:
    """``(section, schema) -> {option: node}``: the schema of each shipped file's sections.

    ``section`` is the config path of the keys (``""``: the top level), ``option`` the
    file (``algo=dual``), ``node`` its mapping of the section.

    Examples:
        >>> from torchrl_dual.recipe.settings.schema import BudgetSettings
        >>> sorted(selections()[("budget", BudgetSettings)])
        ['budget=default', 'budget=paper', 'budget=smoke']
    """
    found: dict[tuple[str, type], dict[str, dict[str, Any]]] = {}

    def add(section: str, schema: type, option: str, node: Any) -> None:
        found.setdefault((section, schema), {})[option] = node if isinstance(node, dict) else {}

    top = _load(CONFIG_DIR / "config.yaml")
    add("", RunSettings, "config.yaml", top)
    add("compile", CompileSettings, "config.yaml", top.get("compile"))
    for group in _GROUPS:
        for name, node in _options(group):
            option = f"{group}={name}"
            if group == "algo":
                for section, schema in ALGORITHMS[name].settings.sections.items():
                    add(section, schema, option, node.get(section))
            elif group == "budget":
                add("budget", BudgetSettings, option, node.get("budget"))
            else:
                add(group, _schema(group, node), option, node)
    return found


def _schema(group: str, node: dict[str, Any]) -> type:
    """The schema a group's file selects by its selector key."""
    if group == "env":
        return ENV_KITS[node["kind"]].settings
    if group == "logger":
        return LOGGERS[node["backend"]].settings
    table = {"critic": CRITICS, "replay": REPLAYS, "collector": COLLECTORS}[group]
    return table[node["name"]][0]


def _value(value: Any) -> str:
    """A YAML value as the page writes it (in backticks)."""
    if value is None:
        text = "null"
    elif isinstance(value, bool):
        text = str(value).lower()
    elif isinstance(value, (list, dict)):
        text = yaml.safe_dump(value, default_flow_style=True, width=1000).strip()
    else:
        text = str(value)
    return f"`{text}`"


def _default(field: str, nodes: dict[str, dict[str, Any]]) -> str:
    """The defaults of ``field`` over the files that set it.

    The most common value first, then the files that set another (``"`0.5`; so2: `1.0`"``).

    Examples:
        >>> _default("lr", {"algo=a": {"lr": 0.1}, "algo=b": {"lr": 0.1}, "algo=c": {"lr": 1}})
        '`0.1`; c: `1`'
    """
    by_value: dict[str, list[str]] = {}
    for option, node in nodes.items():
        if field in node:
            by_value.setdefault(_value(node[field]), []).append(option.split("=")[-1])
    if not by_value:
        return "–"
    common, *others = sorted(by_value, key=lambda value: -len(by_value[value]))
    if len(by_value[common]) == 1 and others:  # no majority: every file names its value
        others = [common, *others]
        return "; ".join(f"{', '.join(by_value[value])}: {value}" for value in others)
    return "; ".join([common, *(f"{', '.join(by_value[value])}: {value}" for value in others)])


def _markdown(text: str) -> str:
    """A docstring's reST as one line of Markdown, ``|`` escaped for a table cell.

    Double backticks and ``:role:`~a.b.x``` become single backticks.
    """
    text = re.sub(r":\w+:`~?(?:[\w.]+\.)?([^`]+)`", r"`\1`", text)
    return " ".join(text.replace("``", "`").replace("|", "\\|").split())


def _accepts(rule: Any) -> str:
    """What a rule accepts, as a phrase (``"an integer >= 1"``)."""
    text = rule.describe()
    text = re.sub(r"^unknown option; choose ", "", text)
    return re.sub(r"^must (be |lie )?", "", text)


def key_table(schema: type, nodes: dict[str, dict[str, Any]]) -> list[str]:
    """The Markdown table of ``schema``'s keys, their defaults read from ``nodes``."""
    rows = ["| key | default | accepts | meaning |", "|---|---|---|---|"]
    for field in dataclasses.fields(schema):
        meta = field.metadata
        cells = (f"`{field.name}`", _default(field.name, nodes), _accepts(meta["rule"]))
        rows.append(f"| {' | '.join(cells)} | {_markdown(meta['doc'])} |")
    return rows


def _summary(schema: type, options: list[str]) -> list[str]:
    summary = _markdown((schema.__doc__ or "").strip().split("\n\n")[0])
    used = ", ".join(f"`{option}`" for option in options)
    return [f"{summary} Set by {used}.", ""]


def key_reference() -> str:
    """``docs/config.md``: every schema's table, grouped by config section."""
    lines = [
        "# Configuration keys",
        "",
        "Every key of the recipe's config, with the default of each shipped config file, "
        "what it accepts and what it means. Generated from the schemas in "
        "`torchrl_dual/recipe/settings/` by "
        "`python -m torchrl_dual.recipe.settings.key_tables docs/config.md` (a test fails "
        "when this page drifts from them); how the groups compose and what a run does: "
        "[recipe.md](recipe.md).",
        "",
    ]
    by_section: dict[str, list[tuple[type, dict[str, dict[str, Any]]]]] = {
        section: [] for section in _SECTIONS
    }
    for (section, schema), nodes in selections().items():
        by_section.setdefault(section, []).append((schema, nodes))
    for section, entries in by_section.items():
        lines += [f"## {f'`{section}`' if section else 'Top level'}", ""]
        for schema, nodes in entries:
            if len(entries) > 1:
                lines += [f"### {schema.__name__}", ""]
            lines += [*_summary(schema, list(nodes)), *key_table(schema, nodes), ""]
    return "\n".join(lines).rstrip("\n") + "\n"


def main(argv: list[str] | None = None) -> None:
    """Writes :func:`key_reference` to the path given (default: standard output)."""
    argv = sys.argv[1:] if argv is None else argv
    text = key_reference()
    if argv:
        Path(argv[0]).write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)


if __name__ == "__main__":
    main()
