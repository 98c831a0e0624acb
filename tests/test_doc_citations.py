"""The docs cite tests that exist (issue 31, item 5): every ``test_*.py`` path the docs
name is a file under ``tests/`` and every ``::test_name`` after it is defined there (a
bare ``::name`` refers to the last file named before it)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md")) + [
    ROOT / "README.md",
    ROOT / "benchmarks" / "README.md",
]
CITATION = re.compile(r"`((?:[\w./-]+/)?test_\w+\.py)?((?:::\w+)*)`")


def citations(text: str) -> list[tuple[str, str | None]]:
    """``(test file, name or None)`` of every citation in ``text``, in order."""
    found, last = [], None
    for match in CITATION.finditer(text):
        path, names = match.group(1), match.group(2)
        if path:
            last = path.removeprefix("tests/")
            found.append((last, None))
        if names and last is not None:
            found += [(last, name) for name in names.strip(":").split("::")]
    return found


def test_citations_reads_paths_and_names():
    text = "`a/test_x.py::test_one`, `::test_two` and `test_y.py`; `tests/b/test_z.py`"
    assert citations(text) == [
        ("a/test_x.py", None),
        ("a/test_x.py", "test_one"),
        ("a/test_x.py", "test_two"),
        ("test_y.py", None),
        ("b/test_z.py", None),
    ]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_every_cited_test_exists(doc):
    missing = []
    for path, name in citations(doc.read_text()):
        file = ROOT / "tests" / path
        if not file.exists():
            missing.append(path)
        elif name is not None and not re.search(rf"(def|class) {name}\b", file.read_text()):
            missing.append(f"{path}::{name}")
    assert missing == []
