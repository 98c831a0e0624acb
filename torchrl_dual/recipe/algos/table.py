"""The table of algorithms the recipe runs, selected by the ``algo`` config group.

Each entry is an :class:`~torchrl_dual.recipe.Algorithm` defined next to its learner;
``torchrl_dual/recipe/config/algo/<name>.yaml`` holds its settings. Adding an algorithm is adding a
learner module, a config file and one line here.
"""

from __future__ import annotations

from torchrl_dual.recipe.algos.calql import CALQL
from torchrl_dual.recipe.algos.dacer import DACER
from torchrl_dual.recipe.algos.diffql import DIFFQL, DIFFQL_LA
from torchrl_dual.recipe.algos.diffuser import DIFFUSER
from torchrl_dual.recipe.algos.edis import EDIS
from torchrl_dual.recipe.algos.iql import IQL
from torchrl_dual.recipe.algos.iql_la import IQL_LA
from torchrl_dual.recipe.algos.so2 import SO2
from torchrl_dual.recipe.settings.algos import Algorithm
from torchrl_dual.recipe.settings.dual import DUAL

ALGORITHMS: dict[str, Algorithm] = {
    "dual": DUAL,
    "iql": IQL,
    "iql_la": IQL_LA,
    "diffql": DIFFQL,
    "diffql_la": DIFFQL_LA,
    "diffuser": DIFFUSER,
    "dacer": DACER,
    "edis": EDIS,
    "calql": CALQL,
    "so2": SO2,
}
"""``algo`` -> :class:`Algorithm`."""
