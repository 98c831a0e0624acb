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


def test_the_other_critics_tutorial_runs(capsys):
    """The Cal-QL, SO2 and balanced-replay examples (once ``python`` blocks of
    pipeline.md, now ``docs/tutorials/5_other_critics.py``) run in the test suite too,
    not only in the docs build, and end with DUALLoss's terms on SO2's ensemble."""
    import runpy

    import torch

    threads = torch.get_num_threads()
    try:
        runpy.run_path(str(DOCS / "tutorials" / "5_other_critics.py"), run_name="tutorial_5")
    finally:
        torch.set_num_threads(threads)  # the tutorial pins one thread
    out = capsys.readouterr().out
    assert "loss_cql=" in out and "['loss_actor', 'loss_qvalue']" in out


def test_the_pipeline_example_is_a_short_script_of_public_names():
    """DUAL on Pendulum end to end (planner, distillation, DUALLoss, ensemble, shift-aware
    noise, collector, replay buffer, refit) in at most 80 lines, importing only names of
    the package's ``__all__``s and touching no private attribute."""
    import ast
    import importlib

    code = python_blocks(DOCS / "pipeline.md")[0][1]
    assert len(code.splitlines()) <= 80
    tree = ast.parse(code)
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module.startswith("torchrl_dual"):
            public = importlib.import_module(node.module).__all__
            assert all(alias.name in public for alias in node.names), node.module
        if isinstance(node, ast.Attribute):
            assert not node.attr.startswith("_"), node.attr
    for part in ("DUALLoss", "make_dual_policy", "progressive_distillation", "Collector"):
        assert part in code


def test_the_readme_snippet_trains_dual_in_twenty_lines():
    """The README's snippet (DUAL's update in a TorchRL loop) on Pendulum transitions: at
    most 20 lines, and its 100 updates lower the critic's loss on a fixed batch."""
    import torch
    from torchrl.envs import GymEnv

    from torchrl_dual.data import TRANSITION_KEYS

    code = python_blocks(DOCS.parent / "README.md")[0][1]
    assert len(code.splitlines()) <= 20
    env = GymEnv("Pendulum-v1")
    env.set_seed(0)
    keys = [key for key in TRANSITION_KEYS if key != "episode"]
    transitions = torch.cat([env.rollout(max_steps=200).select(*keys) for _ in range(2)])
    torch.manual_seed(0)
    namespace = {"__name__": "readme", "transitions": transitions}
    setup, loop = code.split("for _ in range(")
    exec(compile(setup, "README.md", "exec"), namespace)  # noqa: S102 - the README's code
    batch = namespace["replay"].sample()
    before = namespace["loss"](batch.clone())
    exec(compile("for _ in range(" + loop, "README.md", "exec"), namespace)  # noqa: S102
    after = namespace["loss"](batch.clone())
    assert after["loss_qvalue"] < before["loss_qvalue"]
    assert torch.isfinite(after["loss_actor"])
