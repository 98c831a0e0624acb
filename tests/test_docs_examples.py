"""Runs the ``python`` code blocks of the documentation, so the docs cannot rot.

Every fenced ``python`` block of a page in :data:`PAGES` is executed, in order, in one
namespace per page (a later block may use what an earlier one defined). Each block is
compiled under the page's name and padded to its line in the file, so a traceback
points at the failing line of the Markdown page.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs"
PAGES = ("pipeline.md",)
_BLOCK = re.compile(r"^```python[ \t]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def python_blocks(page: Path) -> list[tuple[int, str]]:
    """``(first line number, code)`` of every fenced ``python`` block of ``page``."""
    text = page.read_text(encoding="utf-8")
    return [
        (text.count("\n", 0, match.start(1)) + 1, match.group(1)) for match in _BLOCK.finditer(text)
    ]


def test_block_extraction_finds_code_and_its_line(tmp_path):
    text = "intro\n\n```python\nx = 1\n```\n\n```bash\nls\n```\n```python\ny = x\n```\n"
    page = tmp_path / "page.md"
    page.write_text(text, encoding="utf-8")
    assert python_blocks(page) == [(4, "x = 1\n"), (11, "y = x\n")]


@pytest.mark.parametrize("name", PAGES)
def test_python_blocks_of_the_page_run(name):
    page = DOCS / name
    blocks = python_blocks(page)
    assert blocks, f"{page} has no ```python block to run"
    namespace: dict = {"__name__": f"docs_{page.stem}"}
    for first_line, code in blocks:
        padded = "\n" * (first_line - 1) + code
        exec(compile(padded, str(page), "exec"), namespace)  # noqa: S102 - the docs' own code
