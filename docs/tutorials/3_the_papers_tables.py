"""
The paper's tables as learning-suite cells
==========================================

Tables 1-3 of the paper report the normalized score of DUAL and its baselines after 1M
offline and 1M online steps, on D4RL's locomotion, AntMaze and Adroit data sets. In this
repository each row of a table is one *cell* of the learning suite
(``python -m benchmarks.learning``): the recipe overrides of the row's Minari data set, one
*variant* per column we can run, and the paper's numbers stored next to it for the report.
This tutorial walks from a row of Table 1 to the recipe commands that rerun it, without
running them (one ``budget=paper`` run takes about 2 GPU-hours; :doc:`../reproducing` has
the full procedure). It needs the repository checkout, whose ``benchmarks`` package is not
installed with the wheel.
"""

# %%
# The tables as data
# ------------------
# :data:`COLUMNS` maps each table to its columns: the paper's header and our variant, or
# ``None`` where the method does not run on that critic here. :data:`PAPER` holds the
# paper's mean and standard deviation over its 5 seeds for every (table, row, column).

from benchmarks.learning import paper_tables
from benchmarks.learning import suite as learning
from benchmarks.learning.cells import paper_cells

for header, variant in paper_tables.COLUMNS[1]:
    print(f"{header:10} -> variant {variant}")
print(
    "paper, Table 1, antmaze-umaze-v2, DUAL:", paper_tables.PAPER[(1, "antmaze-umaze-v2", "DUAL")]
)

# %%
# A row is a cell
# ---------------
# :class:`PaperRow` says how a row runs here: its cell name, the recipe overrides that
# select its data set (and, for Table 3's ODRL rows, the online dynamics shift), and why
# it cannot run when Minari has no counterpart of its D4RL data set.

rows = {row.row: row for row in paper_tables.ROWS}
umaze = rows["antmaze-umaze-v2"]
print(umaze.cell, umaze.overrides, umaze.variants)
print(rows["hopper-medium-replay-v2"].unavailable)
print(f"{len(paper_tables.runnable_rows())} of {len(paper_tables.ROWS)} rows run here")

# %%
# Every runnable row is a cell of the suite (``t<table>_<row>``); the suite's default grid
# leaves them out, so they are named explicitly, e.g. all of Table 1's with
# ``--cells $(python -m benchmarks.learning.paper_tables --cells 1)``:

table_1 = [row.cell for row in paper_tables.runnable_rows(1)]
print(" ".join(table_1))
assert set(table_1) <= set(paper_cells())

# %%
# From a cell to recipe runs
# --------------------------
# ``--dry-run`` prints the queue: one recipe run per variant and seed, each a
# ``python recipes/o2o.py budget=paper <row overrides> algo=<variant> seed=<k>`` process,
# and the GPU-hours it would take. The real run adds ``--backend ray --gpus-per-run 1
# device=cuda`` (one GPU per run, :doc:`the next tutorial <4_the_suite_on_ray>`).

import tempfile  # noqa: E402

out = tempfile.mkdtemp()
learning.main(["--budget", "paper", "--cells", umaze.cell, "--variants", "dual", "iql",
               "--seeds", "0", "--out", out, "--dry-run"])  # fmt: skip

# %%
# From runs back to the table
# ---------------------------
# Each finished run leaves a compact JSON under ``benchmarks/results/paper/<cell>/
# <variant>/seed<k>.json``; ``--report-only`` puts ours next to the paper's between the
# ``paper-tables`` markers of ``docs/reproducing.md``. A cell of that table reads
# ``ours / paper``: ours as mean ± sd (the paper's form) with the half-width of the 95 %
# Student-t interval and the number of seeds. With three made-up final scores:

print(paper_tables.ours_cell([{"final_score": s} for s in (91.0, 95.5, 93.0)]))
table = paper_tables.render_tables({}).splitlines()  # no results yet: ours are "—"
print("\n".join([table[2], table[3], *(line for line in table if "`antmaze-umaze" in line)]))
