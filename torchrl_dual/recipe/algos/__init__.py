"""One module per algorithm: its builders and its :class:`Learner`.

DUAL in :mod:`~torchrl_dual.recipe.algos.dual`, each baseline in its own file.
"""
