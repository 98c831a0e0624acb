"""DUAL offline-to-online RL, Algorithm 1 of the paper, end to end (Hydra entry point).

    python recipes/o2o.py                          # PointMaze U-maze, ~10 min of one CPU core
    python recipes/o2o.py env=frozenlake budget=smoke
    python recipes/o2o.py resume=true              # continue an interrupted run

The config tree is ``recipes/config``; the run itself is
:func:`torchrl_dual.recipe.run` (the chosen ``algo``'s entry of
``torchrl_dual.recipe.ALGORITHMS``, for DUAL :func:`torchrl_dual.recipe.run_dual`).
A bad config, a missing device, bad data or an unusable checkpoint ends with one
``error:`` line and exit code 2 (``debug=true`` adds the traceback). See docs/recipe.md.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from torchrl_dual.recipe import check_command_line, hydra_task

CONFIG_DIR = Path(__file__).resolve().parent / "config"


@hydra.main(version_base="1.3", config_path="config", config_name="config")
def main(cfg: DictConfig) -> None:
    hydra_task(cfg)


if __name__ == "__main__":
    check_command_line(CONFIG_DIR)  # composition and config errors: one line, exit 2
    main()
