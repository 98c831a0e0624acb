"""The API reference's sources, generated from the package's ``__all__`` lists.

Every module of ``torchrl_dual`` that declares ``__all__`` (no private, ``_``-prefixed,
part in its path) is read; each public object gets one page, under its *canonical* name:
the shortest public module path exporting it, the top-level ``torchrl_dual`` only for
names nothing else exports (``torchrl_dual.PlannerActor`` is documented as
``torchrl_dual.modules.PlannerActor``). One ``api/<module>.rst`` per public package (and
per leaf module that is the canonical home of a name) lists its names in ``autosummary``
tables, which write the per-name pages; re-exports link to their canonical page.

Run by Sphinx at ``config-inited`` (``setup``), so a name added to an ``__all__`` gets its
page at the next build; ``tests/test_docs_api.py`` checks the generated sources (and a
built ``objects.inv``) against every ``__all__``. Importable without Sphinx.
"""

from __future__ import annotations

import ast
import importlib
import inspect
import re
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "torchrl_dual"
KINDS = ("class", "function", "data")
HEADINGS = {"class": "Classes", "function": "Functions", "data": "Constants"}


@dataclass(frozen=True)
class Export:
    """One ``(module, name)`` of an ``__all__``, and where the object is documented."""

    module: str
    name: str
    canonical: str  # the module whose page documents it
    kind: str  # "class" | "function" | "data"

    @property
    def target(self) -> str:
        """The documented, fully qualified name (``torchrl_dual.objectives.DUALLoss``)."""
        return f"{self.canonical}.{self.name}"


def _declares_all(path: Path) -> bool:
    """Whether the module's source assigns ``__all__`` at top level (without importing)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return any(
        isinstance(node, (ast.Assign, ast.AnnAssign))
        and any(
            isinstance(t, ast.Name) and t.id == "__all__"
            for t in (node.targets if isinstance(node, ast.Assign) else [node.target])
        )
        for node in tree.body
    )


def public_modules(root: Path | None = None) -> list[str]:
    """Every module of the package that declares ``__all__``, private paths excluded."""
    root = Path(importlib.import_module(PACKAGE).__file__).parent if root is None else root
    modules = []
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if parts[-1] == "__init__":
            parts = parts[:-1]
        if any(part.startswith("_") for part in parts) or not _declares_all(path):
            continue
        modules.append(".".join((PACKAGE, *parts)))
    return modules


def _kind(obj: object) -> str:
    if inspect.isclass(obj):
        return "class"
    if callable(obj):
        return "function"
    return "data"


def exports(modules: list[str] | None = None) -> list[Export]:
    """Every ``(module, name)`` of every public ``__all__``, with its canonical home.

    One object exported under one name by several modules is documented once: at the
    shortest module path (fewest dots, then alphabetical), the top-level package last.
    """
    modules = public_modules() if modules is None else modules
    found: dict[tuple[int, str], list[str]] = {}
    objects: dict[tuple[int, str], object] = {}
    pairs = []
    for module_name in modules:
        module = importlib.import_module(module_name)
        for name in module.__all__:
            obj = getattr(module, name)  # an __all__ naming nothing fails here
            key = (id(obj), name)
            found.setdefault(key, []).append(module_name)
            objects[key] = obj
            pairs.append((module_name, name, key))

    def rank(module_name: str) -> tuple[bool, int, str]:
        return (module_name == PACKAGE, module_name.count("."), module_name)

    return [
        Export(module_name, name, min(found[key], key=rank), _kind(objects[key]))
        for module_name, name, key in pairs
    ]


def _title(text: str, char: str = "=") -> str:
    return f"{text}\n{char * len(text)}\n"


def module_page(module_name: str, entries: list[Export]) -> str:
    """The reST of ``api/<module>.rst``: the module's docstring, its own names in
    ``autosummary`` tables (one page each), then its re-exports as links."""
    lines = [
        _title(module_name),
        f".. automodule:: {module_name}\n",
        f".. currentmodule:: {module_name}\n",
    ]
    own = [e for e in entries if e.canonical == module_name]
    for kind in KINDS:
        names = sorted(e.name for e in own if e.kind == kind)
        if not names:
            continue
        lines += [
            _title(HEADINGS[kind], "-"),
            ".. autosummary::",
            "   :toctree: generated",
            f"   :template: autosummary/{kind}.rst",
            "   :nosignatures:\n",
            *(f"   {name}" for name in names),
            "",
        ]
    others = sorted((e for e in entries if e.canonical != module_name), key=lambda e: e.name)
    if others:
        role = {"class": "class", "function": "func", "data": "data"}
        lines += [
            _title("Also exported here", "-"),
            f"Importable as ``from {module_name} import <name>``; documented where they live.\n",
            *(f"* :py:{role[e.kind]}:`{e.name} <{e.target}>`" for e in others),
            "",
        ]
    return "\n".join(lines)


def pages(all_exports: list[Export] | None = None) -> dict[str, str]:
    """``{module: reST}``: one page per public package and per module that is the
    canonical home of a name; ``"index"``: the reference's table of contents."""
    all_exports = exports() if all_exports is None else all_exports
    by_module: dict[str, list[Export]] = {}
    for export in all_exports:
        by_module.setdefault(export.module, []).append(export)
    homes = {e.canonical for e in all_exports}
    listed = sorted(
        m
        for m, entries in by_module.items()
        if m in homes or importlib.import_module(m).__file__.endswith("__init__.py")
    )
    out = {m: module_page(m, by_module[m]) for m in listed}
    index = [
        _title("API reference"),
        "Every public name of ``torchrl_dual``, one page each, generated from the docstrings.",
        "Each name is documented in the module it is shortest to import from; the packages",
        "that re-export it link there.\n",
        ".. toctree::",
        "   :maxdepth: 1\n",
        *(f"   {m}" for m in listed),
        "",
    ]
    out["index"] = "\n".join(index)
    return out


def write(out_dir: Path) -> list[Path]:
    """Writes ``index.rst`` and one ``<module>.rst`` per page into ``out_dir``, leaving
    unchanged files untouched (Sphinx rereads only what changed) and deleting the pages
    (and the per-name pages under ``generated/``) of names no longer exported."""
    all_exports = exports()
    texts = {out_dir / f"{name}.rst": text for name, text in pages(all_exports).items()}
    named = {out_dir / "generated" / f"{e.target}.rst" for e in all_exports}
    out_dir.mkdir(parents=True, exist_ok=True)
    for stale in {*out_dir.glob("*.rst"), *out_dir.glob("generated/*.rst")} - {*texts, *named}:
        stale.unlink()  # autosummary writes the pages of the names exported now
    for path, text in texts.items():
        if not path.exists() or path.read_text(encoding="utf-8") != text:
            path.write_text(text, encoding="utf-8")
    return sorted(texts)


def data_docstring(qualified: str) -> list[str] | None:
    """The doc comment (``#:``) or string after the assignment of a module constant, read
    in the module that assigns it (a re-exporting ``__init__`` has none)."""
    from sphinx.pycode import ModuleAnalyzer  # only at build time

    module_name, name = qualified.rsplit(".", 1)
    obj = getattr(importlib.import_module(module_name), name)
    root = Path(importlib.import_module(PACKAGE).__file__).parent
    for path in sorted(root.rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        candidate = ".".join((PACKAGE, *(parts[:-1] if parts[-1] == "__init__" else parts)))
        if name not in path.read_text(encoding="utf-8"):
            continue
        module = importlib.import_module(candidate)
        if getattr(module, name, None) is not obj:
            continue
        docs = ModuleAnalyzer.for_module(candidate).find_attr_docs()
        if ("", name) in docs:
            return list(docs[("", name)])
    return None


def _fill_data_docstring(app, what, name, obj, options, lines) -> None:
    """``autodoc-process-docstring``: a re-exported constant gets its own doc comment, not
    its type's docstring (``tuple``'s, ``dict``'s), and its value when that is short. Runs
    after napoleon, which would read a first line ``a: b`` as an attribute's type."""
    if what != "data" or not name.startswith(PACKAGE):
        return
    lines[:] = data_docstring(name) or []
    value = repr(obj)
    if isinstance(obj, (str, int, float, tuple, frozenset)) and len(value) <= 100:
        lines += ["", f"The value is ``{value}``."]


_QUOTED = re.compile(r"(``.*?``|`[^`]*`)")
_LONE_BAR = re.compile(r"(?<=[-:/'\"<(\[{])\|(?=\S)")


def _escape_lone_bars(app, what, name, obj, options, lines) -> None:
    """``autodoc-process-docstring``: the paper's ``p(s'|s, a)`` written in prose, outside
    backquotes, is text, not the start of a reST substitution (``|name|``)."""
    if not name.startswith(PACKAGE):
        return
    for i, line in enumerate(lines):
        parts = _QUOTED.split(line)  # even parts lie outside literals and roles
        parts[::2] = [_LONE_BAR.sub(r"\\|", part) for part in parts[::2]]
        lines[i] = "".join(parts)


def _init_signature(app, what, name, obj, options, signature, return_annotation):
    """``autodoc-process-signature``: TorchRL's ``LossModule`` and tensordict's modules
    define ``__new__(cls, *args, **kwargs)``, which autodoc would show as every subclass's
    signature; show the class's ``__init__`` instead."""
    if what != "class" or signature != "(*args, **kwargs)" or not name.startswith(PACKAGE):
        return None
    from sphinx.util.inspect import signature as init_signature
    from sphinx.util.inspect import stringify_signature

    sig = init_signature(obj.__init__, bound_method=True)
    text = stringify_signature(sig, show_return_annotation=False, unqualified_typehints=True)
    return text, return_annotation


# autosummary's one-line summaries end at the first ". ": not at the paper's abbreviations
SUMMARY_ABBREVIATIONS = ("Alg.", "Eq.", "Eqs.", "Sec.", "Thm.", "Fig.", " l.", "(l.")


def _generate(app, config) -> None:
    write(Path(app.srcdir) / "api")


def setup(app) -> dict:
    import sphinx.ext.autosummary as autosummary

    app.setup_extension("sphinx.ext.autodoc")
    abbreviations = autosummary.WELL_KNOWN_ABBREVIATIONS
    autosummary.WELL_KNOWN_ABBREVIATIONS = (*abbreviations, *SUMMARY_ABBREVIATIONS)
    app.connect("autodoc-process-signature", _init_signature)
    app.connect("config-inited", _generate)  # before autosummary reads the sources
    app.connect("autodoc-process-docstring", _fill_data_docstring, priority=600)
    app.connect("autodoc-process-docstring", _escape_lone_bars)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
