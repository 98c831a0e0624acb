"""``benchmarks/learning/paper_tables.py``: the paper's Tables 1-3 as data, the learning-suite cells
that rerun them (``--dry-run`` lists 5 seeds x the paper's methods per row with projected
GPU hours), and the suite run end to end on data sets written here, its report setting our
numbers next to the paper's."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from benchmarks.learning import paper_tables
from benchmarks.learning import suite as learning

pytest.importorskip("h5py", reason="Minari's storage needs h5py: pip install 'minari[hdf5]'")

REPO = Path(__file__).resolve().parents[1]

from torchrl_dual.data.minari_standins import STANDINS, write_standin_dataset  # noqa: E402
from torchrl_dual.recipe import CONFIG_DIR, compose_checked  # noqa: E402
from torchrl_dual.recipe.settings.minari_datasets import FAMILIES  # noqa: E402


def test_every_number_of_the_three_tables_is_stored_with_its_table_row_and_column():
    counts = {t: len({r for tt, r, _ in paper_tables.PAPER if tt == t}) for t in (1, 2, 3)}
    assert counts == {1: 15, 2: 8, 3: 4}
    for table, columns in paper_tables.COLUMNS.items():
        rows = {r for t, r, _ in paper_tables.PAPER if t == table}
        assert len(paper_tables.PAPER) >= len(rows) * len(columns)
        for row in rows:
            assert all((table, row, header) in paper_tables.PAPER for header, _ in columns)
    # spot checks against the paper: Table 1 DUAL on antmaze-umaze-diverse, Table 3 Cal-QL
    assert paper_tables.PAPER[(1, "antmaze-umaze-diverse-v2", "DUAL")] == (78.06, 9.03)
    assert paper_tables.PAPER[(3, "pen-cloned-v1", "Cal-QL: DUAL")] == (-1.09, 0.35)
    assert paper_tables.PAPER[(2, "hopper-kinematic-2.0", "SO2+OFF2ON: Base")] == (51.63, 5.95)


def test_rows_without_minari_data_are_listed_with_the_reason_and_queue_nothing():
    unavailable = {r.row for r in paper_tables.ROWS if r.unavailable}
    assert unavailable == {
        f"{robot}-{d}-v2"
        for robot in ("halfcheetah", "hopper", "walker2d")
        for d in ("medium-replay", "medium-expert")
    } | {"halfcheetah-medium-replay-v2", "halfcheetah-med-gravity-2.0"}
    assert all("Minari has no mujoco/" in r.unavailable for r in paper_tables.ROWS if r.unavailable)
    assert not set(learning.paper_cells()) & {r.cell for r in paper_tables.ROWS if r.unavailable}
    assert not set(learning.paper_cells()) & set(learning.active_cells())


def test_every_paper_cell_and_variant_is_a_valid_recipe_config(tmp_path, monkeypatch):
    """Every row's overrides with every column's variant pass the recipe's checks (the
    data-on-disk check aside: each family's data sets are checked on their stand-ins below)."""
    from torchrl_dual.recipe.settings import envs

    for kind in FAMILIES:
        monkeypatch.setitem(
            envs.ENV_KITS, kind, dataclasses.replace(envs.ENV_KITS[kind], check=None)
        )
    for name, cell in learning.paper_cells().items():
        assert cell.seeds == 5
        for variant in cell.variants:
            overrides = [*cell.overrides, *learning.VARIANTS[variant], "budget=paper"]
            cfg = compose_checked(CONFIG_DIR, [*overrides, f"output_dir={tmp_path}"])
            assert cfg.algo == learning.VARIANTS[variant][0].split("=")[1], (name, variant)
            assert cfg.env.protocol == "d4rl"


def test_every_paper_row_s_data_set_has_a_stand_in():
    """The fixtures cover every data set the tables read (ids as the recipe builds them)."""
    from omegaconf import OmegaConf

    versions = {"antmaze": "v1", "adroit": "v2", "locomotion": "v0"}
    for row in paper_tables.runnable_rows():
        env = dict(o.split("=", 1) for o in row.overrides)
        kind = env["env"] if env["env"] in ("antmaze", "adroit") else "locomotion"
        fields = {
            "task": env.get("env.task", env["env"]),
            "dataset": env["env.dataset"],
            "dataset_version": versions[kind],
        }
        assert FAMILIES[kind].dataset_id(OmegaConf.create(fields)) in STANDINS, row.row


def test_table_1_s_antmaze_rows_read_the_minari_data_set_with_d4rl_s_layout():
    """D4RL's play rows send the ant to a few hand-picked goals, its diverse rows anywhere:
    Minari recorded its play sets in the registered maps (goals in any free cell) and its
    diverse sets in ``*_Diverse_GR`` (the hand-picked ``c`` cells), so each row reads the
    set whose env records D4RL's layout, and its label names that set."""
    rows = {r.row: r for r in paper_tables.ROWS if r.row.startswith("antmaze-")}
    assert len(rows) == 6
    for label, row in rows.items():
        hand_picked = "Diverse_GR" in STANDINS[row.data].env_id
        assert hand_picked == ("-play-" in label), (label, row.data)
        assert f"env.dataset={row.data.split('/')[-1].removesuffix('-v1')}" in row.overrides
        assert f"data: `{row.data}`" in row.label
    assert rows["antmaze-medium-play-v2"].data == "D4RL/antmaze/medium-diverse-v1"
    assert rows["antmaze-large-diverse-v2"].data == "D4RL/antmaze/large-play-v1"
    assert rows["antmaze-umaze-diverse-v2"].data == "D4RL/antmaze/umaze-diverse-v1"


def test_the_dry_run_lists_five_seeds_of_six_methods_per_row_with_gpu_hours(tmp_path, capsys):
    cells = [r.cell for r in paper_tables.runnable_rows(1)]
    flags = ["--results", str(tmp_path), "--out", str(tmp_path / "out")]
    assert learning.main(["--budget", "paper", "--cells", *cells, "--dry-run", *flags]) == 0
    out = capsys.readouterr().out
    commands = [line for line in out.splitlines() if line.startswith("recipes/o2o.py")]
    assert len(commands) == 9 * 6 * 5
    umaze = [c for c in commands if "env.dataset=umaze " in c]
    assert {c.split("algo=")[1].split()[0] for c in umaze} == {
        "iql",
        "edis",
        "diffuser",
        "diffql",
        "dacer",
        "dual",
    }
    assert all("budget=paper" in c for c in commands)
    assert "projected GPU time of the 270 paper runs to go: 270 x 2.33 h" in out


def test_the_paper_cells_run_end_to_end_on_stand_ins_and_the_report_shows_ours_next_to_the_paper_s(
    tmp_path, monkeypatch
):
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(tmp_path / "minari"))
    for dataset_id in ("D4RL/antmaze/umaze-v1", "D4RL/pen/cloned-v2"):
        write_standin_dataset(dataset_id, 2, 20)
    docs = tmp_path / "reproducing.md"
    docs.write_text(
        "# Reproducing\n\n<!-- paper-tables:begin -->\nold\n<!-- paper-tables:end -->\n"
    )
    fast = [
        "budget.offline_updates=5",
        "online.utd_ratio=0.2",
        "budget.online_frames=20",
        "budget.frames_per_batch=20",
        "budget.eval_every=20",
        "budget.checkpoint_every=20",
        "budget.eval_episodes=1",
        "env.max_episode_steps=10",
        "budget.batch_size=16",
    ]
    argv = [
        "--budget", "smoke", "--cells", "t1_antmaze_umaze", "t3_pen_cloned", "--variants", "iql",
        "--seeds", "0", "--jobs", "2", "--out", str(tmp_path / "out"),
        "--results", str(tmp_path / "results"), "--docs", str(tmp_path / "results.md"),
        "--figures", str(tmp_path / "figures"), "--paper-docs", str(docs), *fast,
    ]  # fmt: skip
    assert learning.main(argv) == 0
    for cell in ("t1_antmaze_umaze", "t3_pen_cloned"):
        result = json.loads((tmp_path / "results/smoke" / cell / "iql/seed0.json").read_text())
        assert result["cell"] == cell and "env.protocol" not in " ".join(result["overrides"])
    text = docs.read_text()
    assert "old" not in text and text.count("<!-- paper-tables:begin -->") == 1
    umaze = next(line for line in text.splitlines() if line.startswith("| `antmaze-umaze-v2`"))
    ours, paper = umaze.split(" | ")[1].split(" / ")
    assert ours.endswith("(n = 1)") and paper == "90.38 ± 2.24"
    assert "| `hopper-medium-replay-v2` (Minari has no mujoco/hopper/medium-replay" in text


def test_the_docs_tables_are_the_committed_results():
    """docs/reproducing.md's tables regenerate exactly from benchmarks/results/paper/."""
    from benchmarks.learning.report import load_results

    results_dir = REPO / "benchmarks/results/paper"
    results = load_results(results_dir) if results_dir.exists() else {}
    text = (REPO / "docs/reproducing.md").read_text()
    section = text.split(paper_tables.BEGIN)[1].split(paper_tables.END)[0]
    assert section.strip() == paper_tables.render_tables(results).strip()


def test_our_cell_gives_the_paper_s_sd_and_the_95_percent_t_interval():
    """sd 10 of (60, 70, 80); t(0.975, 2) = 4.303, so the half-width is 4.303 * 10 / sqrt 3."""
    cell = paper_tables.ours_cell([{"final_score": s} for s in (60.0, 70.0, 80.0)])
    assert cell == "70.0 ± 10.0 (95 % t ± 24.8, n = 3)"
    assert paper_tables.ours_cell([{"final_score": 5.0}]) == "5.0 (n = 1)"
    assert paper_tables.ours_cell([{"final_score": float("nan")}]) == "—"
