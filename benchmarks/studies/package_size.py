"""The package's lines by kind: code, docstrings, comments and blank lines.

    python -m benchmarks.studies.package_size              # torchrl_dual/
    python -m benchmarks.studies.package_size some/folder other/module.py   # their sum

A docstring is a module's, class's or function's first string, or a string right after
an assignment in a module or class body (an attribute's docstring, as Sphinx reads
them); each of its lines counts as a docstring line. docs/architecture.md's "Size and
shape" table cites the counts.
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

_DOCUMENTED = (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)


def _is_string(node: ast.stmt) -> bool:
    return (
        isinstance(node, ast.Expr)
        and isinstance(node.value, ast.Constant)
        and isinstance(node.value.value, str)
    )


def docstring_lines(source: str) -> set[int]:
    """The line numbers (from 1) of ``source``'s docstrings."""
    lines: set[int] = set()
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, _DOCUMENTED) or not node.body:
            continue
        body = node.body
        strings = [body[0]] if _is_string(body[0]) else []
        if isinstance(node, (ast.Module, ast.ClassDef)):
            strings += [
                b for a, b in zip(body, body[1:], strict=False)
                if isinstance(a, (ast.Assign, ast.AnnAssign)) and _is_string(b)
            ]  # fmt: skip
        for string in strings:
            lines.update(range(string.lineno, string.end_lineno + 1))
    return lines


def line_kinds(*paths: Path) -> Counter:
    """``{"total", "code", "docstring", "comment", "blank"}`` over the ``.py`` files of ``paths``.

    Each path is a ``.py`` file or a folder (all its ``.py`` files).
    """
    kinds: Counter = Counter()
    files = {f for p in paths for f in ([p] if p.is_file() else p.rglob("*.py"))}
    for path in sorted(files):
        source = path.read_text()
        docs = docstring_lines(source)
        for number, line in enumerate(source.splitlines(), 1):
            text = line.strip()
            kind = "docstring" if number in docs else "blank" if not text else (
                "comment" if text.startswith("#") else "code"
            )  # fmt: skip
            kinds[kind] += 1
            kinds["total"] += 1
    return kinds


def main(argv: list[str] | None = None) -> None:
    """Prints the counts of the files and folders in ``argv`` (default ``torchrl_dual``)."""
    args = sys.argv[1:] if argv is None else argv
    kinds = line_kinds(*(Path(a) for a in args or ["torchrl_dual"]))
    parts = ", ".join(f"{kinds[k]:,} {k}" for k in ("code", "docstring", "blank", "comment"))
    print(f"{kinds['total']:,} lines: {parts}")


if __name__ == "__main__":
    main()
