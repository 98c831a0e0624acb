"""Runs every docstring ``Examples:`` block of the ``torchrl_dual`` package as a doctest.

Equivalent to ``pytest --doctest-modules torchrl_dual`` but works from a plain ``pytest``
at the repository root: modules are discovered at collection time, so a new module is
covered without editing this file. One test per module; nothing is skipped silently:
a module that fails to import fails its test, except when a third-party optional
dependency is missing, which is reported as a skip with its name.
"""

from __future__ import annotations

import doctest
import importlib
import io
import pkgutil
from pathlib import Path

import pytest
import torch

import torchrl_dual

OPTIONFLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE
EXCLUDED: tuple[str, ...] = ()
# Modules whose docstrings must keep at least one example (the public entry points).
MUST_HAVE_EXAMPLES = (
    "torchrl_dual._utils",
    "torchrl_dual.checkpoint",
    "torchrl_dual.data.mc_returns",
    "torchrl_dual.diffusion._fast_path.paired_trunk",
    "torchrl_dual._versioned_cache",
    "torchrl_dual._tensordict_patch",
    "torchrl_dual.diffusion.model",
    "torchrl_dual.diffusion.trajectory_layout",
    "torchrl_dual.modules.actors.planner_actor",
    "torchrl_dual.modules.dual_policy",
    "torchrl_dual.modules.exploration.entropy_regulator",
    "torchrl_dual.modules.exploration.gmm_entropy",
    "torchrl_dual.modules.exploration.shift_aware_noise",
    "torchrl_dual.modules.laplace.laplace_ensemble_actor",
    "torchrl_dual.modules.planner.planner_policy",
    "torchrl_dual.modules.planner.transition_model",
    "torchrl_dual.objectives.calql",
    "torchrl_dual.data.balanced_replay",
    "torchrl_dual.objectives.density_ratio",
    "torchrl_dual.objectives.distillation",
    "torchrl_dual.objectives.so2",
    "torchrl_dual.objectives.update_loop",
)


def _discover(path=torchrl_dual.__path__, prefix: str = "torchrl_dual.") -> list[str]:
    """Every module below ``path`` from the files alone (nothing is imported here, so a
    broken or excluded subpackage cannot break collection)."""
    names = []
    for info in pkgutil.iter_modules(path, prefix):
        if info.name in EXCLUDED:
            continue
        names.append(info.name)
        if info.ispkg:
            names += _discover(
                [str(Path(info.module_finder.path) / info.name.split(".")[-1])], info.name + "."
            )
    return sorted(names)


MODULES = _discover()


def _examples(module_name: str) -> int:
    module = importlib.import_module(module_name)
    tests = doctest.DocTestFinder(exclude_empty=True).find(module, module_name)
    return sum(len(test.examples) for test in tests)


def test_module_discovery_finds_the_whole_package():
    assert set(MUST_HAVE_EXAMPLES) <= set(MODULES)
    assert "torchrl_dual.modules.actors.last_layer_actor" in MODULES
    assert "torchrl_dual.recipe.kits.build" in MODULES


@pytest.mark.parametrize("module_name", MUST_HAVE_EXAMPLES)
def test_the_public_entry_points_keep_their_examples(module_name):
    assert _examples(module_name) > 0, f"{module_name} lost its docstring examples"


@pytest.mark.parametrize("module_name", MODULES)
def test_docstring_examples_run(module_name):
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as err:
        if err.name and not err.name.startswith("torchrl_dual"):
            pytest.skip(f"{module_name} needs the optional dependency {err.name!r}")
        raise
    finder = doctest.DocTestFinder(exclude_empty=True)
    runner = doctest.DocTestRunner(optionflags=OPTIONFLAGS)
    report = io.StringIO()
    torch.manual_seed(0)
    for test in finder.find(module, module_name):
        runner.run(test, out=report.write)
    result = runner.summarize(verbose=False)
    assert result.failed == 0, f"{result.failed} doctest failure(s) in {module_name}:\n" + (
        report.getvalue()
    )
