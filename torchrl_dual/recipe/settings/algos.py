"""The table of algorithms the recipe runs, selected by the ``algo`` config group.

Each entry is an :class:`~torchrl_dual.recipe.settings.algo_common.Algorithm`: its
settings (config sections and their schemas, critics, checks across keys; DUAL's in
:mod:`~torchrl_dual.recipe.settings.dual`, the baselines' in
:mod:`~torchrl_dual.recipe.settings.baselines`) and the learner that runs it, one module
of :mod:`torchrl_dual.recipe.algos` per algorithm, imported when a run starts.
``torchrl_dual/recipe/config/algo/<name>.yaml`` holds its settings' values. Adding an
algorithm is adding a learner module, its settings, a config file and one line here.
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
from torchrl_dual.recipe.settings.lazy import Ref

_ALGOS = "torchrl_dual.recipe.algos"

ALGORITHMS: dict[str, Algorithm] = {
    "dual": Algorithm(DUAL, Ref(f"{_ALGOS}.dual:DualLearner")),
    "iql": Algorithm(IQL, Ref(f"{_ALGOS}.iql:IQLLearner")),
    "iql_la": Algorithm(IQL_LA, Ref(f"{_ALGOS}.iql_la:IQLLALearner")),
    "diffql": Algorithm(DIFFQL, Ref(f"{_ALGOS}.diffql:DiffQLLearner")),
    "diffql_la": Algorithm(DIFFQL_LA, Ref(f"{_ALGOS}.diffql:DiffQLLALearner")),
    "diffuser": Algorithm(
        DIFFUSER,
        Ref(f"{_ALGOS}.diffuser:DiffuserLearner"),
        no_cuda_graph="its update samples its own trajectory windows from the replay "
        "buffer, which a CUDA graph would replay as the same windows every time",
    ),
    "dacer": Algorithm(
        DACER,
        Ref(f"{_ALGOS}.dacer:DACERLearner"),
        no_cuda_graph="its online update steps the entropy regulator every "
        "dacer.entropy_every updates, a Python schedule a CUDA graph would not follow",
    ),
    "edis": Algorithm(EDIS, Ref(f"{_ALGOS}.edis:EDISLearner")),
    "calql": Algorithm(CALQL, Ref(f"{_ALGOS}.calql:CalQLLearner")),
    "so2": Algorithm(SO2, Ref(f"{_ALGOS}.so2:SO2Learner")),
}
"""``algo`` -> :class:`~torchrl_dual.recipe.settings.algo_common.Algorithm`."""
