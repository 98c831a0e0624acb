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

import pytest
import torch

import torchrl_dual

OPTIONFLAGS = doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE


def _discover() -> list[str]:
    names, broken = [], []
    for info in pkgutil.walk_packages(
        torchrl_dual.__path__, prefix="torchrl_dual.", onerror=broken.append
    ):
        names.append(info.name)
    # walk_packages swallows a subpackage whose __init__ fails to import: keep it so
    # that its test fails loudly instead.
    return sorted(set(names) | set(broken))


MODULES = _discover()


def test_module_discovery_finds_the_package():
    assert "torchrl_dual.diffusion.model" in MODULES
    assert "torchrl_dual.objectives.distillation" in MODULES
    assert "torchrl_dual.modules.planner.planner_policy" in MODULES


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
