"""``benchmarks/learning/cells.py`` and ``variants.py``: every cell and variant of the
learning suite is a valid recipe config, and the suite's offline-sharing groups are the
recipe's offline-cache keys."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.learning import suite as learning
from torchrl_dual.recipe import CONFIG_DIR as RECIPE_CONFIG_DIR

REPO = Path(__file__).resolve().parents[1]


def test_every_cell_and_variant_of_the_grid_is_a_valid_recipe_config(tmp_path):
    """A broken variant would otherwise surface hours into the suite: every variant on the
    first cell that runs it, and every cell with its first variant."""
    from torchrl_dual.recipe import compose_checked

    pairs = {(cell.variants[0], name) for name, cell in learning.CELLS.items()}
    for variant in learning.VARIANTS:
        cells = [n for n, c in learning.CELLS.items() if variant in c.variants]
        if cells:
            pairs.add((variant, cells[0]))
    for variant, name in sorted(pairs):
        overrides = [*learning.CELLS[name].overrides, *learning.VARIANTS[variant]]
        cfg = compose_checked(
            RECIPE_CONFIG_DIR, [*overrides, "budget=default", f"output_dir={tmp_path}"]
        )
        assert cfg.algo == learning.VARIANTS[variant][0].split("=")[1], (name, variant)
    in_grid = {v for c in learning.CELLS.values() for v in c.variants}
    assert {v for v, _ in pairs} == in_grid and len(pairs) >= len(learning.CELLS)


def test_runs_the_suite_groups_for_sharing_have_one_recipe_offline_key(tmp_path):
    """The queue's ``sharing_key`` (from ``variants.ONLINE_ONLY``) puts two runs in one
    group exactly when the recipe's offline cache gives them one key (U-maze, seed 0)."""
    from omegaconf import OmegaConf

    from torchrl_dual.recipe import ALGORITHMS, compose_checked
    from torchrl_dual.recipe.o2o.offline_cache import offline_key_config

    runs = [
        learning.Run(name, variant, 0, (*cell.overrides, *learning.VARIANTS[variant]))
        for name, cell in learning.CELLS.items()
        if "env=pointmaze_umaze" in cell.overrides
        for variant in cell.variants
    ]
    keys = {}
    for run in runs:
        cfg = compose_checked(
            RECIPE_CONFIG_DIR,
            [*run.overrides, "budget=default", f"output_dir={tmp_path}"],
        )
        online = getattr(ALGORITHMS[cfg.algo].learner, "online_keys", ())
        config = OmegaConf.to_container(cfg, resolve=True)
        keys[run] = json.dumps(offline_key_config(config, online), sort_keys=True, default=str)
    for a in runs:
        for b in runs:
            same_group = a.sharing_key() == b.sharing_key()
            assert same_group == (keys[a] == keys[b]), (a.cell, a.variant, b.cell, b.variant)


def test_dual_variants_and_their_dual_cells_are_derived_from_the_grid():
    """The paired table's rows come from the grid: DUAL's variants on its own critic,
    paired with the ``dual`` of the cell with the same env overrides."""
    import doctest

    from benchmarks.learning import cells, variants

    assert doctest.testmod(cells).failed == 0 and doctest.testmod(variants).failed == 0
    dual = variants.dual_variants()
    assert {"dual_no_uq", "dual_lambda0", "dual_utd025", "dual_latent_uq"} <= set(dual)
    assert {"dual_no_planner", "dual_no_distillation", "dual_augment"} <= set(dual)
    assert not {"dual", "dual_calql", "dual_so2", "iql", "iql_la"} & set(dual)
    pairs = cells.dual_cells()
    assert pairs["umaze"] == "umaze" and pairs["umaze_online"] == "umaze"
    assert pairs["umaze_ablations"] == "umaze_ablations"  # its own `dual` (another machine)
    assert pairs["umaze_baselines"] == "umaze_ablations"  # Cell.reference
    assert pairs["umaze_rotation"] == "umaze_rotation" and pairs["umaze_20k"] == "umaze_20k"
    for cell, partner in pairs.items():
        assert learning.CELLS[cell].overrides == learning.CELLS[partner].overrides
        assert "dual" in learning.CELLS[partner].variants


def test_a_cell_reference_must_run_dual_with_the_same_overrides(monkeypatch):
    """A :attr:`Cell.reference` pointing at a cell without ``dual``, or with other
    overrides, is a grid error, not a silent pairing with unrelated runs."""
    from benchmarks.learning import cells

    bad = {
        **cells.CELLS,
        "umaze_baselines": cells.Cell(
            ("env=pointmaze_umaze",), ("dual_augment",), 3, "x", reference="medium"
        ),
    }
    monkeypatch.setattr(cells, "CELLS", bad)
    with pytest.raises(ValueError, match="reference 'medium' must run `dual`"):
        cells.dual_cells()


def test_a_retired_cell_is_queued_only_when_named_and_leaves_the_report_s_tables(tmp_path, capsys):
    """``Cell.retired``: the default queue leaves the cell out (its finished runs are not
    redone, its missing ones not started), ``--cells`` can still name it, and the report's
    grid table leaves it out (its "Not in these tables" list says why: test_learning_suite)."""
    assert learning.CELLS["medium"].retired and "medium" not in learning.active_cells()
    results = ["--results", str(tmp_path / "results"), "--dry-run"]
    assert learning.main(results) == 0
    queued = capsys.readouterr().out
    assert "/default/medium_goal/" in queued and "/default/medium/" not in queued
    assert learning.main([*results, "--cells", "medium"]) == 0
    assert "/default/medium/dual/seed0" in capsys.readouterr().out
    header = learning.header_text("default")
    assert "| medium_goal | " in header and "| medium | " not in header


def test_variants_with_more_seeds_queue_them_and_the_header_says_so(monkeypatch):
    """``Cell.more_seeds``: the named variants run at their own seed count, the others at
    the cell's, and the header's seeds column names the exceptions."""
    cell = learning.Cell(("env=frozenlake",), ("dual", "iql"), 2, "t", more_seeds=(("iql", 3),))
    monkeypatch.setitem(learning.CELLS, "t", cell)
    runs, _ = learning.build_queue(["t"], None, None)
    assert sorted((r.variant, r.seed) for r in runs) == [
        ("dual", 0), ("dual", 1), ("iql", 0), ("iql", 1), ("iql", 2)
    ]  # fmt: skip
    assert "| t | t | `env=frozenlake` | `dual`, `iql` | 2 (`iql`: 3) |" in learning.header_text(
        "x"
    )
