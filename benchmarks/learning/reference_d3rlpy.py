"""Reference runs: d3rlpy's IQL and Cal-QL inside the recipe's own run (issue 27).

    python -m benchmarks.learning.reference_d3rlpy algo=iql env=pointmaze_umaze seed=0
    python -m benchmarks.learning.reference_d3rlpy algo=calql seed=0 output_dir=/tmp/calql_ref
    python -m benchmarks.learning.reference_d3rlpy --setup          # only build the reference venv

A baseline's number counts only next to its reference implementation's on the same data.
This script trains d3rlpy 2.8.1's ``IQL`` (``algo=iql``) or ``CalQL`` (``algo=calql``) as a
:class:`~torchrl_dual.recipe.Learner` of the recipe's :func:`~torchrl_dual.recipe.run_o2o`:
the data set, the budget (offline updates, online frames, UTD ratio), the replay (half of
each batch from ``D_offline``), the env, the evaluator, the checkpoints and the
``summary.json`` are the recipe's, the same code ``algo=iql`` runs; only the
networks, the losses and the update are d3rlpy's (its ``impl.update`` on a
``TorchMiniBatch`` built from the recipe's batch). The learning suite runs it as the
variants ``iql_d3rlpy`` and ``calql_d3rlpy`` (``benchmarks/learning/variants.py``).

d3rlpy pins ``gymnasium==1.0.0``; the project's dependencies stay as they are. The script
builds its own virtual environment ``.venv-reference`` (git-ignored; the environment variable
``TORCHRL_DUAL_REFERENCE_VENV`` moves it) on first use: a venv
that sees the calling environment's packages through a ``.pth`` file (the same torch,
TorchRL, Gymnasium-Robotics and MuJoCo, so the env is the same) and holds d3rlpy and its
light dependencies (d3rlpy itself with ``--no-deps``; nothing in the project's venv changes;
pip then warns that d3rlpy wants ``gymnasium==1.0.0``: it runs on the project's 1.x).
Then it re-runs itself with that venv's Python, as the same module from the same working
directory (the repository root, where ``python -m`` finds ``benchmarks``).

What each reference takes from the recipe's config (so it tracks the budget): network
width and depth (d3rlpy's default ``VectorEncoderFactory`` is 256 x 2 = the default
budget's), batch size, γ, τ, learning rates, IQL's expectile and β, Cal-QL's penalty
weight and sample count; everything else is d3rlpy's default (``max_weight=100``,
``min/max_logstd``, Cal-QL's automatic entropy tuning from 1); Cal-QL's penalty weight is
fixed at ``critic.min_q_weight`` (d3rlpy's Lagrange tuning off), as ``algo=calql`` has it.
"""

from __future__ import annotations

import os
import site
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
VENV = Path(os.environ.get("TORCHRL_DUAL_REFERENCE_VENV", REPO / ".venv-reference"))
"""The reference venv (``TORCHRL_DUAL_REFERENCE_VENV`` overrides where it is built)."""
MODULE = "benchmarks.learning.reference_d3rlpy"
"""This module's name, for ``python -m`` (the learning suite runs it so, from the repo root)."""
D3RLPY = "d3rlpy==2.8.1"
D3RLPY_DEPS = ("gym==0.26.2", "structlog", "colorama", "click", "dataclasses-json", "scikit-learn")
"""d3rlpy 2.8.1's requirements beyond torch, tqdm, h5py and gymnasium, which the
project's environment provides (d3rlpy's ``gymnasium==1.0.0`` pin is left out)."""


def venv_python() -> Path:
    return VENV / "bin" / "python"


def build_venv() -> Path:
    """``.venv-reference``: this interpreter's packages (a ``.pth`` that adds its site
    directories) plus d3rlpy, installed with ``--no-deps``; returns its Python."""
    python = venv_python()
    if python.exists() and _has_d3rlpy(python):
        return python
    subprocess.run([sys.executable, "-m", "venv", str(VENV)], check=True)
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    parents = [p for p in site.getsitepackages() if Path(p).is_dir()]
    (Path(purelib) / "_project_env.pth").write_text(
        "".join(f"import site; site.addsitedir({p!r})\n" for p in parents)
    )
    pip = [str(python), "-m", "pip", "install", "-q"]
    subprocess.run([*pip, "--no-deps", D3RLPY], check=True)
    subprocess.run([*pip, *D3RLPY_DEPS], check=True)  # the parent's packages count as installed
    if not _has_d3rlpy(python):
        raise SystemExit(f"error: {VENV} has no importable d3rlpy; delete it and run --setup")
    return python


def _has_d3rlpy(python: Path) -> bool:
    probe = subprocess.run([str(python), "-c", "import d3rlpy"], capture_output=True)
    return probe.returncode == 0


ALGOS = ("iql", "calql")
"""The recipe's algorithms with a d3rlpy reference (``reference_learners.REFERENCES``)."""


def check_overrides(argv: list[str]) -> None:
    """One ``error:`` line and exit code 2 for a command line the recipe refuses or an
    ``algo`` without a reference, before the reference venv is built."""
    from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked, user_errors

    with user_errors(debug="debug=true" in argv):
        cfg = compose_checked(CONFIG_DIR, argv)
        if cfg.algo not in ALGOS:
            raise ConfigError("algo", cfg.algo, "no d3rlpy reference; choose one of iql, calql")


def main(argv: list[str]) -> None:
    if argv[:1] == ["--setup"]:
        print(build_venv())
        return
    check_overrides(argv)
    try:
        import d3rlpy  # noqa: F401
    except ImportError:
        python = build_venv()
        os.execv(str(python), [str(python), "-m", MODULE, *argv])
    from benchmarks.learning.reference_learners import run_reference

    run_reference(argv)


if __name__ == "__main__":
    main(sys.argv[1:])
