"""docs/recipe.md documents every key of the recipe's shipped config tree: each leaf key of
every ``config/**/*.yaml`` appears in backticks on the page, by its dotted name or, in its
section's table, by its last part (``planner.horizon`` as ``horizon``)."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import yaml

from torchrl_dual.recipe import CONFIG_DIR

DOC = Path(__file__).resolve().parents[1] / "docs" / "recipe.md"


def leaf_keys(node: dict, prefix: str = "") -> Iterator[str]:
    """The dotted leaf keys of a config file's mapping (Hydra's own keys left out)."""
    for key, value in node.items():
        if key in ("defaults", "hydra"):
            continue
        if isinstance(value, dict):
            yield from leaf_keys(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}"


def documented_names(markdown: str) -> set[str]:
    """Every name inside a backtick span outside code fences, split at spaces, commas,
    ``=`` and brackets."""
    prose = re.sub(r"^```.*?^```", "", markdown, flags=re.MULTILINE | re.DOTALL)
    spans = [span for line in prose.splitlines() for span in re.findall(r"`([^`]+)`", line)]
    return {name for span in spans for name in re.split(r"[\s,=()\[\]]+", span) if name}


def test_leaf_keys_and_documented_names_are_read_as_the_page_writes_them():
    assert list(leaf_keys({"defaults": [], "a": {"b": 1, "c": {"d": 2}}, "e": 3})) == [
        "a.b",
        "a.c.d",
        "e",
    ]
    page = "`planner.horizon`, `hidden`, `depth` (`x=y`)\n```bash\n`inside_a_fence`\n```\n"
    assert documented_names(page) == {"planner.horizon", "hidden", "depth", "x", "y"}


def test_every_key_of_the_config_tree_is_documented():
    names = documented_names(DOC.read_text(encoding="utf-8"))
    keys = set()
    for path in Path(CONFIG_DIR).rglob("*.yaml"):
        keys.update(leaf_keys(yaml.safe_load(path.read_text()) or {}))
    assert len(keys) > 100
    missing = sorted(
        key
        for key in keys
        if key not in names and key.rsplit(".", 1)[-1] not in names
        and not any(name.endswith("." + key.rsplit(".", 1)[-1]) for name in names)
    )  # fmt: skip
    assert missing == []
