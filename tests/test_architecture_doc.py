"""docs/architecture.md describes the package as it is (issue 28, item 7): every module
it names exists, every part of the package has a row, every recipe module is listed."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "torchrl_dual"
DOC = (ROOT / "docs" / "architecture.md").read_text()


def _section(title: str) -> str:
    start = DOC.index(f"## {title}\n")
    end = DOC.find("\n## ", start + 1)
    return DOC[start : end if end != -1 else None]


def _first_column(section: str) -> list[str]:
    """The backticked names in the first column of the section's table rows."""
    cells = [line.split("|")[1] for line in section.splitlines() if line.startswith("| `")]
    return [name for cell in cells for name in re.findall(r"`([^`]+)`", cell)]


def _exists(path: str) -> bool:
    """A path as the doc writes it: from the repository root when it starts with one of
    its top-level folders, else under ``torchrl_dual/`` (or, for the recipe's subpackages
    named alone, under ``torchrl_dual/recipe/``)."""
    path = path.split("::")[0]
    if path.split("/")[0] in {"torchrl_dual", "recipes", "benchmarks", "tests", "docs"}:
        return (ROOT / path).exists()
    return (PACKAGE / path).exists() or (PACKAGE / "recipe" / path).exists()


def test_every_path_the_doc_names_exists():
    named = set(re.findall(r"`((?:[\w.]+/)+[\w.]*(?:\.py)?)`", DOC))
    named = {n for n in named if n.endswith((".py", "/")) and not n.startswith(("http", "D4RL/"))}
    assert len(named) > 60
    missing = sorted(n for n in named if not _exists(n))
    assert missing == []


def test_every_part_of_the_package_has_a_row():
    rows = _first_column(_section("The parts"))
    tops = {p.name + ("/" if p.is_dir() else "") for p in PACKAGE.iterdir()}
    tops -= {"__init__.py", "__pycache__/", "py.typed"}
    unlisted = sorted(top for top in tops if not any(r.startswith(top) for r in rows))
    assert unlisted == []


def test_every_recipe_module_is_listed_once():
    listed = _first_column(_section("The recipe's modules"))
    actual = {
        str(p.relative_to(PACKAGE))
        for p in (PACKAGE / "recipe").rglob("*.py")
        if not (p.name == "__init__.py" and p.parent != PACKAGE / "recipe")
    }
    assert len(listed) == len(set(listed))
    assert set(listed) == actual


def test_the_checks_see_a_missing_module():
    assert not _exists("recipe/no_such_module.py")
    assert _exists("recipe/o2o/run.py") and _exists("benchmarks/learning/suite.py")


def test_one_dual_update_reads_through_at_most_five_files_each_calling_the_next():
    """Issue 28's goal: the reading path of one DUAL update is at most 5 files, and each
    file of the doc's table hands over to the next by the name the doc gives."""
    start = DOC.index("### Reading one DUAL update")
    table = DOC[start : DOC.index("\n## ", start)]
    files = [
        line.split("|")[2].strip().strip("`")
        for line in table.splitlines()
        if re.match(r"\| \d", line)
    ]
    assert files == [
        "recipe/cli.py",
        "recipe/settings/algos.py",
        "recipe/o2o/loop.py",
        "recipe/algos/dual.py",
        "trainers/stepper.py",
    ]
    text = {f: (PACKAGE / f).read_text() for f in files}
    assert "run_o2o(cfg, ALGORITHMS[cfg.algo].learner)" in text["recipe/cli.py"]
    assert (
        '"dual": Algorithm(DUAL, Ref(f"{_ALGOS}.dual:DualLearner"))'
        in text["recipe/settings/algos.py"]
    )
    loop = text["recipe/o2o/loop.py"]
    assert "optimization_stepper=updates" in loop and "run.update" in loop
    assert "self.run.learner.after_updates()" in loop
    counted = (PACKAGE / "recipe/o2o/update_step.py").read_text()  # run.update: LearnerUpdates
    assert "**self(sub_batch)" in counted and "metrics = self.update(batch)" in counted
    dual = text["recipe/algos/dual.py"]
    update = dual[dual.index("    def update(self, batch") :]
    update = update[: update.index("\n    def ")]
    assert "self.stepper.update(batch)" in update and "DUALLoss(" in dual
    stepper = text["trainers/stepper.py"]
    assert "def update(self, batch" in stepper
    assert "self.loss.critic_loss(" in stepper and "self.loss.actor_loss(" in stepper
