"""The wheel as a user installs it: the recipe, its configs and its entry points ship.

A wheel built from this checkout is installed into a fresh virtual environment that
reuses the installed dependencies (a ``.pth`` file adds this environment's site
directories, so nothing is downloaded but the build backend), and the recipe runs from an
empty directory through the ``torchrl-dual`` console script and ``python -m
torchrl_dual.recipe``, importing ``torchrl_dual`` from the wheel, not from the checkout.
"""

from __future__ import annotations

import os
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FAST = (  # the smoke budget cut further
    "budget=smoke",
    "budget.offline_updates=20",
    "budget.planner_updates=20",
    "budget.distill_updates=[5,5,5,5,5]",
    "budget.online_frames=100",
    "budget.frames_per_batch=50",
    "budget.eval_every=100",
    "budget.eval_episodes=2",
    "progress=false",
    "num_threads=1",
)

pytestmark = pytest.mark.long_running(seconds=45)  # starts first under xdist


def user_env() -> dict[str, str]:
    """The environment of a user who installed the wheel: no ``PYTHONPATH`` into a checkout."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    return {**env, "OMP_NUM_THREADS": "1"}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)],
        check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    (built,) = out.glob("torchrl_dual-*.whl")
    return built


@pytest.fixture(scope="module")
def venv(tmp_path_factory, wheel) -> Path:
    """A fresh venv with the wheel installed and this environment's packages visible."""
    root = tmp_path_factory.mktemp("venv") / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(root)], check=True, timeout=300)
    python = root / "bin" / "python"
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True, capture_output=True, text=True,
    ).stdout.strip()  # fmt: skip
    parents = [p for p in site.getsitepackages() if Path(p).is_dir()]
    (Path(purelib) / "_parent_env.pth").write_text(
        "".join(f"import site; site.addsitedir({p!r})\n" for p in parents)
    )
    subprocess.run(  # --ignore-installed: the parent's editable install counts as installed
        [str(python), "-m", "pip", "install", "-q", "--no-deps", "--ignore-installed", str(wheel)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    return root


def test_the_wheel_holds_the_configs_the_typing_marker_and_the_license(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert "torchrl_dual/recipe/config/config.yaml" in names
    assert "torchrl_dual/recipe/config/algo/dual.yaml" in names
    assert "torchrl_dual/recipe/__main__.py" in names and "torchrl_dual/py.typed" in names
    assert any(n.endswith(".dist-info/LICENSE") or "/licenses/" in n for n in names)
    assert not [n for n in names if n.startswith(("benchmarks/", "tests/", "recipes/"))]
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    assert (
        "torchrl-dual = torchrl_dual.recipe:main"
        in zipfile.ZipFile(wheel).read(entry_points).decode()
    )


def test_the_console_script_runs_the_recipe_from_an_empty_directory(venv, tmp_path):
    empty = tmp_path / "empty"
    empty.mkdir()
    env = user_env()
    where = subprocess.run(
        [str(venv / "bin" / "python"), "-c", "import torchrl_dual; print(torchrl_dual.__file__)"],
        cwd=empty, env=env, check=True, capture_output=True, text=True,
    ).stdout  # fmt: skip
    assert where.startswith(str(venv)), where
    proc = subprocess.run(
        [str(venv / "bin" / "torchrl-dual"), *FAST, f"data_cache_dir={tmp_path / 'data'}"],
        cwd=empty, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    run_dir = empty / "outputs" / "pointmaze_umaze" / "dual" / "smoke" / "seed0"
    assert (run_dir / "summary.json").exists() and (run_dir / "o2o.log").exists()


def test_python_dash_m_reports_a_bad_value_in_one_line_with_exit_2(venv, tmp_path):
    proc = subprocess.run(
        [str(venv / "bin" / "python"), "-m", "torchrl_dual.recipe", "budget.online_frames=-1"],
        cwd=tmp_path, env=user_env(), capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        "error: budget.online_frames=-1: must be an integer >= 0"
    ]


HIDE_RECIPE_DEPS = """
import sys
from importlib.machinery import PathFinder

HIDDEN = {"gymnasium", "gymnasium_robotics", "mujoco", "hydra", "omegaconf", "matplotlib", "minari"}


class HidingPathFinder(PathFinder):  # as if those distributions were not installed
    @classmethod
    def find_spec(cls, name, path=None, target=None):
        if name.split(".")[0] in HIDDEN:
            return None
        return PathFinder.find_spec(name, path, target)


sys.meta_path[:] = [HidingPathFinder if f is PathFinder else f for f in sys.meta_path]
from torchrl_dual import (
    DiffusionPlannerLoss, DistillationLoss, LaplaceEnsembleActor, ShiftAwareNoise,
    WeightedMAPActorLoss,
)
import torchrl_dual.diffusion, torchrl_dual.modules, torchrl_dual.objectives
print(sorted(m for m in sys.modules if m.split(".")[0] in HIDDEN))
"""


def test_the_core_and_the_five_public_names_import_without_the_recipe_s_dependencies():
    """``import torchrl_dual`` (losses, modules, diffusion) needs torch, TorchRL and
    TensorDict only: Hydra, OmegaConf, Gymnasium(-Robotics), MuJoCo, matplotlib and Minari
    hidden from the import system, the import works and loads none of them."""
    proc = subprocess.run(
        [sys.executable, "-c", HIDE_RECIPE_DEPS],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert proc.stdout.strip() == "[]"
