"""Every public name of the package has a page in the API reference.

The reference's sources are generated from the ``__all__`` lists by ``docs/_ext/api_pages.py``
at each Sphinx build. Here, without Sphinx: every module that declares ``__all__`` (found
by reading the sources, not by the generator) has its names on a generated page, each
documented once under a name that resolves to the same object. With
``TORCHRL_DUAL_DOCS_INVENTORY`` pointing at a built site's ``objects.inv`` (CI sets it after
``sphinx-build``), every one of them must also be in that inventory, with its role.
"""

from __future__ import annotations

import importlib
import importlib.util
import os
import re
import sys
import zlib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGE_DIR = REPO / "torchrl_dual"
_spec = importlib.util.spec_from_file_location("api_pages", REPO / "docs" / "_ext" / "api_pages.py")
api_pages = sys.modules["api_pages"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(api_pages)

ROLES = {"class": "py:class", "function": "py:function", "data": "py:data"}


def modules_declaring_all() -> list[str]:
    """Public modules whose source has a top-level ``__all__`` line (a text search)."""
    found = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        parts = path.relative_to(REPO).with_suffix("").parts
        parts = parts[:-1] if parts[-1] == "__init__" else parts
        if any(p.startswith("_") for p in parts) or not re.search(
            r"^__all__\b", path.read_text(encoding="utf-8"), re.MULTILINE
        ):
            continue
        found.append(".".join(parts))
    return found


def documented(pages: dict[str, str]) -> dict[str, str]:
    """``{fully qualified name: kind}`` of every name an ``autosummary`` table of the
    generated pages lists (each gets its own page)."""
    names = {}
    for module, text in pages.items():
        for table in re.finditer(r"\.\. autosummary::\n((?:   .*\n|\n)+)", text + "\n"):
            kind = re.search(r":template: autosummary/(\w+)\.rst", table.group(1)).group(1)
            for line in table.group(1).splitlines():
                if line.strip() and not line.strip().startswith(":"):
                    names[f"{module}.{line.strip()}"] = kind
    return names


def resolve(qualified: str) -> object:
    module, name = qualified.rsplit(".", 1)
    return getattr(importlib.import_module(module), name)


def missing_names(modules: list[str], names: dict[str, str]) -> list[str]:
    """``module.name`` of every ``__all__`` entry no documented name resolves to."""
    by_object = {}
    for qualified in names:
        by_object.setdefault((id(resolve(qualified)), qualified.rsplit(".", 1)[1]), qualified)
    return [
        f"{module}.{name}"
        for module in modules
        for name in importlib.import_module(module).__all__
        if (id(resolve(f"{module}.{name}")), name) not in by_object
    ]


@pytest.fixture(scope="module")
def reference() -> tuple[list[str], dict[str, str]]:
    modules = modules_declaring_all()
    pages = api_pages.pages(api_pages.exports(modules))
    return modules, pages


def test_the_generator_reads_every_module_that_declares_all(reference):
    modules, _ = reference
    assert "torchrl_dual.objectives" in modules and "torchrl_dual.trainers.stepper" in modules
    assert not any("._" in m for m in modules)  # private modules are not the API
    assert api_pages.public_modules() == modules


def test_every_public_name_is_documented_once(reference):
    modules, pages = reference
    names = documented(pages)
    assert missing_names(modules, names) == []
    objects = [(id(resolve(q)), q.rsplit(".", 1)[1]) for q in names]
    assert len(objects) == len(set(objects)), "an object has two pages"
    # the new public API sits in its subpackage; the top-level package re-exports
    for qualified in (
        "torchrl_dual.objectives.DUALLoss",
        "torchrl_dual.trainers.CriticActorStepper",
    ):
        assert names[qualified] == "class"
    assert names["torchrl_dual.data.TRANSITION_KEYS"] == "data"
    assert "torchrl_dual.PlannerActor" not in names
    assert "torchrl_dual.modules.PlannerActor" in names
    assert "<torchrl_dual.modules.PlannerActor>" in pages["torchrl_dual"]  # linked from the root


def test_a_name_added_to_an_all_without_a_page_is_reported(reference):
    modules, pages = reference
    names = documented(pages)
    names.pop("torchrl_dual.objectives.DUALLoss")
    assert missing_names(modules, names) == ["torchrl_dual.objectives.DUALLoss"]


def test_the_reference_lists_every_module_page(reference):
    _, pages = reference
    index = pages["index"]
    for module in pages:
        if module != "index":
            assert f"\n   {module}\n" in index


def inventory(path: Path) -> set[tuple[str, str]]:
    """``(name, role)`` entries of a Sphinx ``objects.inv`` (version 2)."""
    data = path.read_bytes()
    header_end = 0
    for _ in range(4):  # four header lines, then the zlib stream
        header_end = data.index(b"\n", header_end) + 1
    assert data.startswith(b"# Sphinx inventory version 2"), path
    entries = set()
    for line in zlib.decompress(data[header_end:]).decode().splitlines():
        match = re.match(r"(.+?)\s+(\S+:\S+)\s+-?\d+\s", line)
        if match:
            entries.add((match.group(1), match.group(2)))
    return entries


def test_the_built_inventory_holds_every_public_name(reference):
    built = os.environ.get("TORCHRL_DUAL_DOCS_INVENTORY")
    if not built:
        pytest.skip("set TORCHRL_DUAL_DOCS_INVENTORY to a built site's objects.inv (CI does)")
    entries = inventory(Path(built))
    modules, pages = reference
    names = documented(pages)
    assert missing_names(modules, names) == []
    absent = [q for q, kind in names.items() if (q, ROLES[kind]) not in entries]
    assert absent == []
    assert [m for m in pages if m != "index" and (m, "py:module") not in entries] == []
