"""docs/config.md, the key tables generated from the recipe's schemas: it is what the
generator prints today, every key of every shipped YAML file is a row of the schema
that checks it, and every row says what its key means."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from torchrl_dual.recipe.settings.key_tables import CONFIG_DIR, key_reference, main, selections

GROUPS = ("env", "budget", "critic", "collector", "replay", "logger")
PAGE = Path(__file__).resolve().parents[1] / "docs" / "config.md"


def test_the_page_is_what_the_schemas_generate():
    assert PAGE.read_text(encoding="utf-8") == key_reference(), (
        "docs/config.md drifted from the schemas: "
        "python -m torchrl_dual.recipe.settings.key_tables docs/config.md"
    )


def test_each_file_sets_exactly_the_keys_of_the_schema_that_checks_it():
    found = selections()
    files = {option for nodes in found.values() for option in nodes}
    assert len(files) == len(list(Path(CONFIG_DIR).rglob("*.yaml")))
    for (section, schema), nodes in found.items():
        fields = {field.name for field in dataclasses.fields(schema)}
        for option, node in nodes.items():
            keys = set(node)
            if section == "":  # config.yaml: the groups have their own tables; the algo
                keys -= {"defaults", "hydra", "compile", *GROUPS}  # files set `algo`
                fields -= {"algo"}
            assert keys == fields, (option, section, sorted(keys ^ fields))


def test_every_key_says_what_it_means_in_one_table_cell():
    schemas = {schema for _, schema in selections()}
    fields = [field for schema in schemas for field in dataclasses.fields(schema)]
    assert len(fields) > 150
    for field in fields:
        doc = field.metadata["doc"]
        assert doc and doc == doc.strip() and "\n" not in doc, field.name


def test_a_drifted_page_is_rewritten_by_the_module(tmp_path):
    page = tmp_path / "config.md"
    page.write_text("stale")
    main([str(page)])
    assert page.read_text(encoding="utf-8") == key_reference()
