"""The config schema is light: it imports neither torch nor TorchRL (issue 28, item 2).

A bad config value is reported before anything heavy is imported; the option names the
schema keeps (``settings/names.py``) equal the library's tables; every builder the
tables name (a ``Ref``) exists.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from torchrl_dual.recipe.settings import names
from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.envs import ENV_KITS
from torchrl_dual.recipe.settings.lazy import Ref
from torchrl_dual.recipe.settings.o2o import COLLECTORS, REPLAYS
from torchrl_dual.recipe.settings.parts import CRITICS

HEAVY = (
    "torch",
    "torchrl",
    "tensordict",
    "gymnasium",
    "gymnasium_robotics",
    "mujoco",
    "matplotlib",
    "minari",
    "numpy",
)
"""What the schema and the command line's checks must not import."""

_BLOCKED_RUN = textwrap.dedent(
    """
    import importlib.abc, runpy, sys
    HEAVY = {heavy!r}

    class Blocked(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in HEAVY:
                raise ImportError(f"blocked by the test: {{name}}")
            return None

    sys.meta_path.insert(0, Blocked())
    sys.argv = ["torchrl-dual", *{argv!r}]
    runpy.run_module("torchrl_dual.recipe", run_name="__main__")
    """
)


def _run_blocked(*argv: str) -> subprocess.CompletedProcess:
    code = _BLOCKED_RUN.format(heavy=HEAVY, argv=list(argv))
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("budget.online_frames=-5", "error: budget.online_frames=-5: must be an integer >= 0"),
        ("algo=nope", "error: algo=nope: unknown option; choose one of calql,"),
        ("planner.schedul=cosine", "error: unknown key 'planner.schedul'; did you mean"),
        ("distillation.final_steps=64", "error: distillation.final_steps=64: must be <="),
        ("collector=multi_sync", "collector.num_workers"),  # a check across keys
        ("algo=iql critic=calql", "error: critic=calql: iql supports iql"),
    ],
)
def test_a_bad_config_is_reported_without_torch(override, message):
    """Per-key rules, unknown keys and the checks across keys run with torch, TorchRL,
    Gymnasium, MuJoCo, matplotlib and numpy unimportable."""
    result = _run_blocked(*override.split(), "output_dir=/tmp/unused")
    if override == "collector=multi_sync":  # valid: it gets as far as the env's check
        assert "blocked by the test" in result.stderr
        return
    assert result.returncode == 2, result.stderr
    assert message in result.stderr, result.stderr
    assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "blocked by the test" not in result.stderr


def test_the_blocker_blocks():
    """The harness above would let a heavy import through unnoticed if it did not block."""
    code = _BLOCKED_RUN.format(heavy=HEAVY, argv=[]).replace(
        'runpy.run_module("torchrl_dual.recipe", run_name="__main__")', "import torch"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode != 0 and "blocked by the test: torch" in result.stderr


def test_importing_the_schema_imports_nothing_heavy():
    code = (
        "import sys\n"
        "import torchrl_dual.recipe.settings.schema, torchrl_dual.recipe.cli\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "[]"


def test_the_names_equal_the_library_tables():
    from torchrl_dual.diffusion import LATENTS, SAMPLERS, SCHEDULES
    from torchrl_dual.envs import FROZENLAKE_MAPS, POINTMAZE_IDS, SHIFTS, shift_names
    from torchrl_dual.modules.dual_policy import UNCERTAINTIES
    from torchrl_dual.objectives import PENALTY_LAYOUTS, WEIGHTINGS
    from torchrl_dual.objectives.so2 import TARGET_REDUCTIONS
    from torchrl_dual.recipe.algos.diffql import ACTIVATIONS
    from torchrl_dual.recipe.settings.baselines import DIFFQL_ACTIVATIONS

    assert names.SCHEDULES == tuple(SCHEDULES)
    assert names.SAMPLERS == tuple(SAMPLERS)
    assert names.LATENTS == tuple(LATENTS)
    assert names.UNCERTAINTIES == tuple(UNCERTAINTIES)
    assert names.WEIGHTINGS == tuple(WEIGHTINGS)
    assert names.PENALTY_LAYOUTS == tuple(PENALTY_LAYOUTS)
    assert names.TARGET_REDUCTIONS == tuple(TARGET_REDUCTIONS)
    assert names.FROZENLAKE_MAPS == tuple(FROZENLAKE_MAPS)
    assert names.POINTMAZE_MAZES == tuple(POINTMAZE_IDS)
    kinds = {kind for shift in SHIFTS.values() for kind in shift.kinds}
    assert set(names.SHIFTS_BY_KIND) == kinds
    for kind in kinds:
        assert names.SHIFTS_BY_KIND[kind] == shift_names(kind), kind
    assert DIFFQL_ACTIVATIONS == tuple(ACTIVATIONS)


def _refs():
    for name, algorithm in ALGORITHMS.items():
        yield f"ALGORITHMS[{name}].learner", algorithm.learner
    for name, kit in ENV_KITS.items():
        for field in ("load_data", "make_env", "make_evaluator", "action_projection", "check"):
            yield f"ENV_KITS[{name}].{field}", getattr(kit, field)
    for name, critic in CRITICS.items():
        yield f"CRITICS[{name}].make", critic.make
    for name, replay in REPLAYS.items():
        yield f"REPLAYS[{name}].make", replay.make
    for name, collector in COLLECTORS.items():
        yield f"COLLECTORS[{name}].make", collector.make
        yield f"COLLECTORS[{name}].push", collector.push


def test_every_builder_a_table_names_exists():
    from torchrl_dual.recipe.o2o.learner import Learner

    refs = [(where, ref) for where, ref in _refs() if isinstance(ref, Ref)]
    assert len(refs) > 30
    for where, ref in refs:
        assert callable(ref.resolve()), where
    for name, algorithm in ALGORITHMS.items():
        assert issubclass(algorithm.learner.resolve(), Learner), name
    assert ALGORITHMS["dacer"].learner.online_keys  # attributes read through the Ref


def test_a_ref_names_what_is_missing():
    with pytest.raises(ValueError, match="module:attribute"):
        Ref("no_colon")
    with pytest.raises(AttributeError, match="has no attribute 'nope'"):
        Ref("torchrl_dual.recipe.settings.lazy:nope").resolve()
    assert Ref("os:sep") == Ref("os:sep") and len({Ref("os:sep"), Ref("os:sep")}) == 1
