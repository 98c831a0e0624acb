"""DUAL offline-to-online RL, Algorithm 1 of the paper, end to end (Hydra entry point).

    python recipes/o2o.py                          # PointMaze U-maze, 5 to 10 min of one CPU core
    python recipes/o2o.py env=frozenlake budget=smoke
    python recipes/o2o.py resume=true              # continue an interrupted run

The same program as the ``torchrl-dual`` console script and ``python -m
torchrl_dual.recipe`` (:func:`torchrl_dual.recipe.main`), kept so that commands written
for a clone keep working. The config tree ships in the package
(``torchrl_dual/recipe/config``, :data:`torchrl_dual.recipe.CONFIG_DIR`); the run itself
is the chosen ``algo``'s entry of ``torchrl_dual.recipe.ALGORITHMS``. A bad config, a
missing device, bad data or an unusable checkpoint ends with one ``error:`` line and exit
code 2 (``debug=true`` adds the traceback). See docs/recipe.md.
"""

from torchrl_dual.recipe import main

if __name__ == "__main__":
    main()
