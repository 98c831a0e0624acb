"""The package's import rule (docs/architecture.md, "Which part may import which").

Every ``torchrl_dual`` import of every module is read from its source (no import runs)
and checked against the table below: a part imports only the parts listed for it.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "torchrl_dual"

# the library's parts (what the recipe's builders compose; ``from torchrl_dual import``
# of the top-level names is not a part and always allowed)
LIBRARY = ("data", "diffusion", "modules", "objectives", "envs", "transforms", "_utils")
# part (module prefix) -> module prefixes it may import; the longest matching part wins.
ALLOWED: dict[str, tuple[str, ...]] = {
    "_utils": (),
    "_versioned_cache": (),
    "_tensordict_patch": (),
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
    "objectives": ("objectives", "diffusion", "modules.actors", "_utils", "_versioned_cache"),
    # DUAL in TorchRL's Trainer: the library's parts, not the recipe
    "trainers": ("trainers", "evaluation", "_tensordict_patch", *LIBRARY),
    # the recipe: settings (no torch, nothing else) < kits < o2o < parts < algos
    "recipe.settings": ("recipe.settings",),
    # the entry: the schema, the signal handling (plain Python), and the loop inside run()
    # once the config is valid (torch-free up to there: tests/recipe/test_settings_light.py)
    "recipe.cli": (
        "recipe.settings",
        "recipe.o2o.interrupts",
        "recipe.o2o.run_lock",
        "recipe.o2o.loop",
    ),
    "recipe.kits": (
        "recipe.kits",
        "recipe.settings",
        "data",
        "envs",
        "evaluation",
        "transforms",
        "_utils",
    ),
    "recipe.o2o": (
        "recipe.o2o",
        "recipe.kits",
        "recipe.settings",
        "checkpoint",
        "data",
        "objectives",
        "_tensordict_patch",
    ),
    "recipe.parts": (
        "recipe.parts",
        "trainers.hooks",  # Alg. 1 line 17's schedule, written once (RefitSchedule)
        "recipe.o2o",
        "recipe.kits",
        "recipe.settings",
        *LIBRARY,
    ),
    "recipe.algos": (
        "recipe.algos",
        "trainers.stepper",  # Alg. 1's update, written once (CriticActorStepper)
        "trainers.hooks",  # Alg. 1 line 17's schedule, written once (RefitSchedule)
        "recipe.parts",
        "recipe.o2o",
        "recipe.kits",
        "recipe.settings",
        *LIBRARY,
    ),
    "recipe": ("recipe", "_lazy"),  # the recipe's __init__ (lazy) and __main__
    "_lazy": (),
    "": ("",),  # the package's own __init__ re-exports the public names (lazily)
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


def _import_graph(files: dict[str, Path], resolve) -> dict[str, set[str]]:
    """``module -> modules it imports`` (``TYPE_CHECKING`` imports included: a cycle
    hidden from the interpreter is still one for the reader)."""
    graph: dict[str, set[str]] = {name: set() for name in files}
    for name, path in files.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                targets = [node.module, *(f"{node.module}.{a.name}" for a in node.names)]
            elif isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                continue
            graph[name] |= {t for t in map(resolve, targets) if t is not None and t != name}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                other = stack.pop()
                component.append(other)
                if other == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in graph:
        if node not in index:
            visit(node)
    return found


def test_the_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycles_in_the_package():
    files = {f"torchrl_dual.{_module_name(p)}".rstrip("."): p for p in SOURCES}

    def resolve(target: str) -> str | None:
        return target if target in files else None

    assert _cycles(_import_graph(files, resolve)) == []


BENCHMARKS = sorted((PACKAGE.parent / "benchmarks").rglob("*.py"))
"""Every module of the ``benchmarks`` package and its subpackages."""


def _benchmark_module(path: Path) -> str:
    """``benchmarks/learning/suite.py`` -> ``benchmarks.learning.suite`` (a package's
    ``__init__.py``: the package)."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_no_import_cycles_in_the_benchmarks():
    files = {_benchmark_module(p): p for p in BENCHMARKS}

    def resolve(target: str) -> str | None:  # by package name: benchmarks.learning.cells
        return target if target in files else None

    assert len(files) > 30 and "benchmarks.learning.cells" in files
    graph = _import_graph(files, resolve)
    assert "benchmarks.learning.variants" in graph["benchmarks.learning.cells"]
    assert _cycles(graph) == []


def test_the_benchmarks_import_each_other_by_package_name():
    """A benchmark imports another as ``benchmarks.<folder>.<name>``, never by its bare
    name with its folder put on ``sys.path`` (and no module changes ``sys.path``)."""
    stems = {p.stem for p in BENCHMARKS}
    bare = []
    for path in BENCHMARKS:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            else:
                continue
            bare += [f"{path.name}: {n}" for n in names if n.split(".")[0] in stems]
    assert bare == []
    tests = sorted((PACKAGE.parent / "tests").rglob("*.py"))
    hacks = [
        f"{path.name}: {line.strip()}"
        for path in [*BENCHMARKS, *tests]
        for line in path.read_text().splitlines()
        if re.search(r"sys\.path(\.insert|\.append|\[:0\]).*benchmarks", line)
    ]
    assert hacks == []


def test_the_benchmarks_import_public_names_only():
    """No benchmark imports a private module or name of the package (a ``_`` prefix)."""
    private = []
    for path in BENCHMARKS:
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("torchrl_dual"):
                names = [*node.module.split("."), *(alias.name for alias in node.names)]
            elif isinstance(node, ast.Import):
                names = [
                    p
                    for a in node.names
                    if a.name.startswith("torchrl_dual")
                    for p in a.name.split(".")
                ]
            else:
                continue
            private += [f"{path.name}: {n}" for n in names if n.startswith("_")]
    assert private == []


def _run_attributes(path: Path) -> set[str]:
    """The attributes read of ``run`` or ``self.run`` in a module."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if not isinstance(node, ast.Attribute):
            continue
        owner = node.value
        if isinstance(owner, ast.Name) and owner.id == "run":
            found.add(node.attr)
        elif isinstance(owner, ast.Attribute) and owner.attr == "run":
            if isinstance(owner.value, ast.Name) and owner.value.id == "self":
                found.add(node.attr)
    return found


def test_learners_and_parts_use_the_run_through_its_narrow_context():
    """``recipe/algos`` and ``recipe/parts`` read of the run only what ``RunContext``
    declares (a narrow context instead of the whole run), and its config only typed
    (``run.settings``, never the raw ``DictConfig``)."""
    from torchrl_dual.recipe.o2o.learner import RunContext

    declared = set(RunContext.__annotations__) | {
        name for name in vars(RunContext) if not name.startswith("_")
    }
    sources = [
        *(PACKAGE / "recipe" / "algos").glob("*.py"),
        *(PACKAGE / "recipe" / "parts").glob("*.py"),
    ]
    used = {(path.name, attr) for path in sources for attr in _run_attributes(path)}
    assert {attr for _, attr in used} >= {"settings", "data", "env"}  # the reader finds them
    assert "cfg" not in declared
    assert sorted((name, attr) for name, attr in used if attr not in declared) == []


# Where the composed config is read as such: its checks, the entry point, and the two
# places that turn it into the run's typed settings (``O2ORun``, ``run_o2o``).
READS_THE_COMPOSED_CONFIG = {
    "recipe/cli.py",
    "recipe/o2o/loop.py",
    "recipe/o2o/run.py",
    "recipe/kits/pointmaze.py",  # check_pointmaze, ENV_KITS' check of the PointMaze cells
}


def _imports_dict_config(path: Path) -> bool:
    return any(
        isinstance(node, ast.ImportFrom)
        and node.module == "omegaconf"
        and any(alias.name == "DictConfig" for alias in node.names)
        for node in ast.walk(ast.parse(path.read_text()))
    )


def test_only_the_checks_and_the_entry_read_the_composed_config():
    """Outside ``recipe/settings`` (the config's checks), the recipe reads the validated
    config typed, as ``RecipeSettings``: the run, its collectors, replays, loggers and
    summary, the env kits' builders, the learners and their parts."""
    recipe = PACKAGE / "recipe"
    readers = {
        path.relative_to(PACKAGE).as_posix()
        for path in recipe.rglob("*.py")
        if "settings" not in path.relative_to(recipe).parts and _imports_dict_config(path)
    }
    assert "recipe/o2o/run.py" in readers  # the reader finds them
    assert readers == READS_THE_COMPOSED_CONFIG
