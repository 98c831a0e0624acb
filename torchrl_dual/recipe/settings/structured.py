"""The schemas as Hydra structured configs, stored in Hydra's ``ConfigStore``.

Each section's schema (a dataclass of :func:`~torchrl_dual.recipe.settings.rules.key`
fields) is stored in the group ``recipe_schema`` (:func:`schema_nodes` names them), and every
shipped YAML file extends its section's schema in its defaults list
(``/recipe_schema/budget@budget``, ``/recipe_schema/env_pointmaze@_here_``,
``/recipe_schema/dual_planner@planner``, ...). Hydra then composes each section as a structured
config: a key its schema lacks, or a value of the wrong type (``budget.online_frames=abc``),
is refused while composing, and each value has its field's type (``env.shift_angle=60``
is ``60.0``). The rules check what a type cannot say: ranges, choices and the checks
across keys (:func:`~torchrl_dual.recipe.settings.schema.validate_config`). The top-level
keys (``seed``, ``device``, ...) are left untyped while composing, since the sections an
algorithm adds are not known before it is chosen; the rules check them.

:func:`store_schemas` runs before every composition of the recipe's config
(:func:`~torchrl_dual.recipe.compose_checked`, the command line).

Examples:
    >>> from omegaconf import OmegaConf
    >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked
    >>> cfg = compose_checked(CONFIG_DIR, ["budget=smoke"])
    >>> OmegaConf.get_type(cfg.budget).__name__, OmegaConf.get_type(cfg.planner).__name__
    ('BudgetSettings', 'PlannerSettings')
"""

from __future__ import annotations

from hydra.core.config_store import ConfigStore

from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.envs import ENV_KITS
from torchrl_dual.recipe.settings.o2o import COLLECTORS, LOGGERS, REPLAYS
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.recipe.settings.schema import BudgetSettings, CompileSettings

SCHEMA_GROUP = "recipe_schema"
"""The ``ConfigStore`` group of the schemas (``/recipe_schema/<name>`` in a defaults list)."""


def schema_nodes() -> dict[str, type]:
    """Each stored schema by its name in :data:`SCHEMA_GROUP`.

    ``budget``, ``compile``, ``env_<kind>``, ``critic_<name>``, ``replay_<name>``,
    ``collector_<name>``, ``logger_<backend>`` and ``<algo>_<section>``.
    """
    nodes: dict[str, type] = {"budget": BudgetSettings, "compile": CompileSettings}
    nodes.update({f"env_{kind}": kit.settings for kind, kit in ENV_KITS.items()})
    nodes.update({f"critic_{name}": entry[0] for name, entry in CRITICS.items()})
    nodes.update({f"replay_{name}": entry[0] for name, entry in REPLAYS.items()})
    nodes.update({f"collector_{name}": entry.settings for name, entry in COLLECTORS.items()})
    nodes.update({f"logger_{name}": entry.settings for name, entry in LOGGERS.items()})
    for algo, entry in ALGORITHMS.items():
        sections = entry.settings.sections
        nodes.update({f"{algo}_{section}": schema for section, schema in sections.items()})
    return nodes


def store_schemas() -> None:
    """Stores those of :func:`schema_nodes` that Hydra's ``ConfigStore`` lacks."""
    store = ConfigStore.instance()
    stored = store.repo.get(SCHEMA_GROUP, {})
    for name, schema in schema_nodes().items():
        if f"{name}.yaml" not in stored:
            store.store(group=SCHEMA_GROUP, name=name, node=schema)
