"""The recipes: ``python recipes/o2o.py ...`` (or ``import recipes.o2o`` from the repo root)."""
