"""The package's import rule (docs/architecture.md, "Which part may import which").

Every ``torchrl_dual`` import of every module is read from its source (no import runs)
and checked against the table below: a part imports only the parts listed for it.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "torchrl_dual"

# part (module prefix) -> module prefixes it may import; the longest matching part wins.
ALLOWED: dict[str, tuple[str, ...]] = {
    "_utils": (),
    "_versioned_cache": (),
    "checkpoint": (),
    "evaluation": (),
    "transforms": ("transforms", "_utils"),
    "envs": ("envs",),
    "data": ("data", "envs"),
    "diffusion": ("diffusion",),
    "diffusion._fast_path": ("diffusion", "_versioned_cache"),
    "modules._gaussian": (),
    "modules.planner": ("modules.planner", "diffusion", "_utils"),
    "modules.actors": ("modules.actors", "modules.planner", "diffusion", "_utils"),
    "modules.laplace": (
        "modules.laplace",
        "modules.actors",
        "modules.planner",
        "modules._gaussian",
        "_utils",
        "_versioned_cache",
    ),
    "modules.exploration": ("modules.exploration", "modules._gaussian", "_utils"),
    "modules.dual_policy": ("modules",),
    "modules": ("modules",),
    "objectives": ("objectives", "diffusion", "modules.actors", "_utils"),
    "recipe": ("",),  # the composition root may import every part
    "": ("",),  # the package's own __init__ re-exports the public names
}
# private subpackages and the only modules outside them that may import them
PRIVATE_CLIENTS = {"diffusion._fast_path": ("modules.actors.planner_actor",)}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(p for p in parts if p != "__init__")


def _covers(prefix: str, name: str) -> bool:
    return prefix == "" or name == prefix or name.startswith(prefix + ".")


def _part(name: str) -> str:
    return max((part for part in ALLOWED if _covers(part, name)), key=len)


def _imports(path: Path) -> list[str]:
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
        elif isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
    prefix = "torchrl_dual."
    return [n[len(prefix) :] for n in names if n.startswith(prefix)]


SOURCES = sorted(PACKAGE.rglob("*.py"))


def test_the_rule_sees_every_module():
    assert len(SOURCES) > 40
    assert _part("modules.laplace.laplace_ensemble_actor") == "modules.laplace"
    assert _part("diffusion._fast_path.paired_trunk") == "diffusion._fast_path"
    assert _imports(PACKAGE / "modules" / "dual_policy.py")  # the reader finds imports


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(PACKAGE)))
def test_each_module_imports_only_what_its_part_may(path):
    name = _module_name(path)
    part = _part(name)
    for imported in _imports(path):
        assert any(_covers(allowed, imported) for allowed in ALLOWED[part]), (
            f"{name} (part {part!r}) imports torchrl_dual.{imported}; allowed: {ALLOWED[part]}"
        )
        for private, clients in PRIVATE_CLIENTS.items():
            if _covers(private, imported) and not _covers(private, name):
                assert name in clients, f"{name} imports the private {private}"
