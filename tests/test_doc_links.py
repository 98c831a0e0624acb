"""Every relative link of the README, docs/ and benchmarks/README.md reaches an existing
file, and its ``#anchor`` an existing heading of that file (GitHub's heading slugs)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [
    REPO / "README.md",
    *sorted((REPO / "docs").glob("*.md")),
    REPO / "benchmarks" / "README.md",
]


def heading_slugs(markdown: str) -> set[str]:
    """GitHub's anchors of the headings (outside code fences): lower case, punctuation
    but ``-`` and ``_`` dropped, spaces to ``-``, repeats suffixed ``-1``, ``-2``, ..."""
    slugs, seen, fenced = set(), {}, False
    for line in markdown.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        match = None if fenced else re.match(r"^#{1,6}\s+(.*)$", line)
        if match is None:
            continue
        text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", match.group(1).strip())
        slug = re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        slugs.add(slug if count == 0 else f"{slug}-{count}")
    return slugs


def test_heading_slugs_follow_github():
    text = "# A `b_c` (issue 29, 2026-12-05)\n```\n# not a heading\n```\n## Again\n## Again\n"
    assert heading_slugs(text) == {"a-b_c-issue-29-2026-12-05", "again", "again-1"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(REPO)))
def test_every_relative_link_reaches_its_file_and_heading(page):
    broken = []
    for target in re.findall(r"\]\(([^)\s]+)\)", page.read_text()):
        if target.startswith(("http://", "https://", "mailto:")):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in heading_slugs(dest.read_text()):
            broken.append(f"{target}: no heading with that anchor in {dest.name}")
    assert not broken, broken
