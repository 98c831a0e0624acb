"""The schemas as Hydra structured configs in the ConfigStore (settings/structured.py).

A Hydra app that extends a stored schema is typed and checked while Hydra composes it; a
recipe config merged into its schemas (``typed_config``) is typed section by section, and
``RecipeSettings`` reads its instances from it.
"""

from __future__ import annotations

import dataclasses

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.errors import HydraException
from omegaconf import OmegaConf
from omegaconf.errors import ValidationError

from torchrl_dual.recipe import ALGORITHMS, CONFIG_DIR, compose_checked
from torchrl_dual.recipe import cli as recipe_cli
from torchrl_dual.recipe.settings.rules import as_settings
from torchrl_dual.recipe.settings.schema import BudgetSettings, RunSettings, config_sections
from torchrl_dual.recipe.settings.structured import (
    SCHEMA_GROUP,
    RecipeSettings,
    schema_nodes,
    store_schemas,
    typed_config,
)


def test_a_hydra_app_extending_a_stored_schema_is_typed_and_checked_as_it_composes(tmp_path):
    store_schemas()
    assert set(ConfigStore.instance().repo[SCHEMA_GROUP]) == {f"{n}.yaml" for n in schema_nodes()}
    smoke = OmegaConf.load(CONFIG_DIR / "budget" / "smoke.yaml").budget
    app = {"defaults": [f"/{SCHEMA_GROUP}/budget@budget", "_self_"], "budget": smoke}
    OmegaConf.save(OmegaConf.create(app), tmp_path / "app.yaml")
    with initialize_config_dir(str(tmp_path), version_base="1.3"):
        cfg = compose("app", ["budget.online_frames=500"])
        assert OmegaConf.get_type(cfg.budget) is BudgetSettings
        assert cfg.budget.online_frames == 500
        with pytest.raises(HydraException, match="online_frames"):
            compose("app", ["budget.online_frames=abc"])  # an untyped section would take it


@pytest.mark.parametrize("algo", sorted(ALGORITHMS))
def test_each_section_is_its_schema_with_the_rules_values_typed_by_its_fields(algo, tmp_path):
    cfg = compose_checked(CONFIG_DIR, ["budget=smoke", f"algo={algo}", f"output_dir={tmp_path}"])
    typed = typed_config(cfg)
    assert OmegaConf.get_type(typed) is RunSettings
    settings = RecipeSettings.of(cfg)
    for name, schema in config_sections(cfg).items():
        assert OmegaConf.get_type(typed[name]) is schema, name
        section = settings.sections[name]
        assert type(section) is schema and section == as_settings(schema, cfg[name]), name
        for field in dataclasses.fields(schema):
            if field.type in ("float", float):
                value = getattr(section, field.name)
                assert isinstance(value, float) or value is None, (name, field.name, value)
    assert type(settings.env.shift_angle) is float and cfg.env.shift_angle == 60  # 60 -> 60.0
    assert settings.run == RunSettings(
        **{f.name: cfg[f.name] for f in dataclasses.fields(RunSettings)}
    )


def test_a_value_its_field_cannot_hold_is_refused_when_the_config_is_typed(tmp_path):
    cfg = compose_checked(CONFIG_DIR, ["budget=smoke", f"output_dir={tmp_path}"])
    OmegaConf.update(cfg, "budget.batch_size", "many")  # past the rules: a typed field refuses it
    with pytest.raises(ValidationError, match="batch_size"):
        typed_config(cfg)


def test_the_recipe_s_composition_does_not_see_the_stored_schemas(monkeypatch):
    store_schemas()
    seen = []

    def composing(*args, **kwargs):  # what Hydra's store holds while the recipe composes
        seen.append(SCHEMA_GROUP in ConfigStore.instance().repo)
        return compose(*args, **kwargs)

    monkeypatch.setattr(recipe_cli, "compose", composing)
    cfg = compose_checked(CONFIG_DIR, ["budget=smoke"])
    assert seen == [False]  # hidden: Hydra deep-copies the whole store at each composition
    assert OmegaConf.get_type(cfg.budget) is dict  # its files do not extend them
    assert SCHEMA_GROUP in ConfigStore.instance().repo  # and they are back afterwards
