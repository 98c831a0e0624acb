"""The table of algorithms the recipe runs, selected by the ``algo`` config group.

Each entry is an :class:`~torchrl_dual.recipe.settings.algo_common.Algorithm`: its config
sections and their schemas, its critics, its checks across keys and a
:class:`~torchrl_dual.recipe.settings.lazy.Ref` to its learner in
:mod:`torchrl_dual.recipe.algos`. ``torchrl_dual/recipe/config/algo/<name>.yaml`` holds
its settings. Adding an algorithm is adding a learner module, its settings, a config
file and one line here.
"""

from __future__ import annotations

from torchrl_dual.recipe.settings.algo_common import Algorithm
from torchrl_dual.recipe.settings.baselines import (
    CALQL,
    DACER,
    DIFFQL,
    DIFFQL_LA,
    DIFFUSER,
    EDIS,
    IQL,
    IQL_LA,
    SO2,
)
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
"""``algo`` -> :class:`~torchrl_dual.recipe.settings.algo_common.Algorithm`."""
