"""Every command-line entry point the README and docs name ends bad input alike: exit code
2, one ``error:`` line, no traceback, before any run starts (in this process, as
``recipe_runner`` runs scripts; ``test_config_errors.py`` and ``test_packaging.py`` run
the real processes)."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from recipe_runner import failed, run_console_script, run_module, run_script

ENTRY_POINTS: dict[str, Callable] = {
    "recipes/o2o.py": lambda *a: run_script("recipes/o2o.py", *a),
    "torchrl-dual": lambda *a: run_console_script("torchrl-dual", *a),
    "python -m torchrl_dual.recipe": lambda *a: run_module("torchrl_dual.recipe", *a),
    "python -m benchmarks.learning.reference_d3rlpy": lambda *a: run_module(
        "benchmarks.learning.reference_d3rlpy", "algo=iql", *a
    ),
}
BAD = {  # override: what the error line says
    "budget.online_frames=-5": "budget.online_frames=-5: must be an integer >= 0",
    "env=nope": "env=nope: unknown option; choose one of ",
    "budget.onlin_frames=5": "unknown key 'budget.onlin_frames'; did you mean budget.online_frames?",
    "recipe.algo=x": "unknown key 'recipe.algo'",
    "seed=abc": "seed=abc: must be an integer",
    "budget.online_frames=[1,2": "malformed override 'budget.online_frames=[1,2'",
    "--nope": "--nope",
    "+seed=1": "+seed=1: seed exists already; write seed=1 to change it",
}


@pytest.mark.parametrize("override", BAD)
@pytest.mark.parametrize("entry", ENTRY_POINTS)
def test_bad_input_ends_in_one_line_and_exit_2_at_every_entry_point(entry, override, tmp_path):
    line = failed(ENTRY_POINTS[entry](override, f"output_dir={tmp_path / 'run'}"))
    assert BAD[override] in line
    assert not (tmp_path / "run").exists()  # refused before anything was written


@pytest.mark.parametrize(
    ("entry", "override", "says"),
    [
        ("python -m benchmarks.learning.reference_d3rlpy", "algo=dual", "no d3rlpy reference"),
    ],
)
def test_entry_points_refuse_their_own_bad_input(entry, override, says, tmp_path):
    line = failed(ENTRY_POINTS[entry](override, f"output_dir={tmp_path / 'run'}"))
    assert says in line


def test_the_recipe_s_flag_parser_is_hydra_s():
    """``cli.hydra_flags`` mirrors the parser ``@hydra.main`` uses (a private Hydra API,
    read here only): the same flags, destinations and choices."""
    from hydra._internal.utils import get_args_parser

    from torchrl_dual.recipe.cli import hydra_flags

    def described(parser):
        return {
            action.dest: (sorted(action.option_strings), action.nargs, action.choices)
            for action in parser._actions
        }

    assert described(hydra_flags()) == described(get_args_parser())
