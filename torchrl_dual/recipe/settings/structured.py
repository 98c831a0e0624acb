"""The recipe's schemas as Hydra structured configs in the ``ConfigStore``; the typed config.

:func:`store_schemas` stores each schema (a dataclass of
:func:`~torchrl_dual.recipe.settings.rules.key` fields, which documents its keys) in the
``ConfigStore`` group ``recipe_schema``: ``run`` (the top-level keys), ``budget``,
``compile``, ``env_<kind>``, ``critic_<name>``, ``replay_<name>``, ``collector_<name>``,
``logger_<backend>`` and ``<algo>_<section>`` (:func:`schema_nodes`). A Hydra app of
your own extends them in its defaults list (``- /recipe_schema/budget@budget``) and
Hydra types and checks those sections as it composes.

:func:`typed_config` merges a recipe config into the stored schemas of its sections: each
section becomes a structured config of its schema (a value of the wrong type is refused,
an integer in a float field becomes a float), and :meth:`RecipeSettings.of` reads the
instances from it. The recipe's own YAML files do not extend the schemas: Hydra would then
load and merge about ten more nodes per composition, each composition 40 to 75 ms slower
(docs/architecture.md); the rules check the composed config instead
(:func:`~torchrl_dual.recipe.validate_config`).

Examples:
    >>> from omegaconf import OmegaConf
    >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked
    >>> typed = typed_config(compose_checked(CONFIG_DIR, ["budget=smoke"]))
    >>> OmegaConf.get_type(typed.budget).__name__, typed.env.shift_angle
    ('BudgetSettings', 60.0)
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf, open_dict

from torchrl_dual.recipe.settings.algos import ALGORITHMS
from torchrl_dual.recipe.settings.envs import ENV_KITS
from torchrl_dual.recipe.settings.loggers import LOGGERS
from torchrl_dual.recipe.settings.o2o import COLLECTORS, REPLAYS
from torchrl_dual.recipe.settings.parts import CRITICS
from torchrl_dual.recipe.settings.schema import (
    BudgetSettings,
    CompileSettings,
    RunSettings,
    config_sections,
)

SCHEMA_GROUP = "recipe_schema"
"""The ``ConfigStore`` group of the schemas (``/recipe_schema/<name>`` in a defaults list)."""


def schema_nodes() -> dict[str, type]:
    """Each schema by its name in :data:`SCHEMA_GROUP`."""
    nodes: dict[str, type] = {
        "run": RunSettings,
        "budget": BudgetSettings,
        "compile": CompileSettings,
    }
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
    """Stores those of :func:`schema_nodes` that Hydra's ``ConfigStore`` lacks.

    Call it before composing a Hydra app whose defaults list extends them.

    Examples:
        >>> from hydra.core.config_store import ConfigStore
        >>> store_schemas()
        >>> schemas = ConfigStore.instance().repo["recipe_schema"]
        >>> "budget.yaml" in schemas, "dual_planner.yaml" in schemas, "env_pointmaze.yaml" in schemas
        (True, True, True)
    """
    store = ConfigStore.instance()
    stored = store.repo.get(SCHEMA_GROUP, {})
    for name, schema in schema_nodes().items():
        if f"{name}.yaml" not in stored:
            store.store(group=SCHEMA_GROUP, name=name, node=schema)


def typed_config(cfg: DictConfig) -> DictConfig:
    """``cfg`` merged into the stored schemas of its top-level keys and sections.

    Args:
        cfg (DictConfig): a recipe config (:func:`~torchrl_dual.recipe.compose_checked`'s).

    Returns:
        DictConfig: a new config whose root is typed by ``run``'s schema and each section
        by its own (:func:`~torchrl_dual.recipe.settings.schema.config_sections`), its
        interpolations kept.

    Raises:
        omegaconf.errors.ValidationError: a value of a type its schema's field refuses.
    """
    store_schemas()
    store = ConfigStore.instance()
    by_schema = {schema: name for name, schema in schema_nodes().items()}
    typed = store.load(f"{SCHEMA_GROUP}/run.yaml").node
    with open_dict(typed):
        for section, schema in config_sections(cfg).items():
            typed[section] = store.load(f"{SCHEMA_GROUP}/{by_schema[schema]}.yaml").node
    return OmegaConf.merge(typed, cfg)


@dataclass(frozen=True)
class RecipeSettings:
    """A validated config, typed: what the learners read.

    The top-level keys (:class:`RunSettings`: ``settings.device``, ``settings.seed``,
    ...) and every section as an instance of its schema (``settings.budget``,
    ``settings.critic``, the algorithm's ``settings.actor``, ...), plain Python values
    with the interpolations resolved, each value of its field's type (:meth:`of` a config
    that passed :func:`~torchrl_dual.recipe.validate_config`).

    Examples:
        >>> from torchrl_dual.recipe import CONFIG_DIR, compose_checked
        >>> settings = RecipeSettings.of(compose_checked(CONFIG_DIR, ["budget=smoke"]))
        >>> settings.device, settings.planner.num_steps, settings.budget.distill_updates
        ('cpu', 32, [10, 10, 10, 10, 10])
        >>> type(settings.critic).__name__, "actor" in settings.sections
        ('IQLCriticSettings', True)
    """

    run: RunSettings
    sections: dict[str, Any]

    @classmethod
    def of(cls, cfg: DictConfig) -> RecipeSettings:
        """The typed view of ``cfg`` (which passed :func:`~torchrl_dual.recipe.validate_config`).

        The instances of :func:`typed_config`'s sections and top-level keys.
        """
        typed = typed_config(cfg)
        run = {f.name: typed[f.name] for f in fields(RunSettings)}
        sections = {name: OmegaConf.to_object(typed[name]) for name in typed if name not in run}
        return cls(RunSettings(**run), sections)

    def get(self, name: str, default: Any = None) -> Any:
        """A section or top-level key, ``default`` where the config has none."""
        return self.sections.get(name, getattr(self.run, name, default))

    def __getattr__(self, name: str) -> Any:
        """A section (``settings.actor``), else a top-level key (``settings.device``)."""
        if name in ("run", "sections"):  # not set yet (copy, pickle): no recursion
            raise AttributeError(name)
        if name in self.sections:
            return self.sections[name]
        return getattr(self.run, name)
