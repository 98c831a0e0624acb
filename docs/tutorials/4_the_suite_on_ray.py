"""
The learning suite on Ray
=========================

The learning suite (``python -m benchmarks.learning``) runs a grid of recipe runs,
cells × variants × seeds, each a ``python recipes/o2o.py ...`` process, and writes one
compact JSON per finished run and a report. ``--backend local`` (the default) runs
``--jobs`` of them at a time on this machine; ``--backend ray`` submits one Ray task per
run to a cluster. A finished run is skipped when the grid is submitted again, and a run
lost with its node is retried from its checkpoint.

On a cluster (:doc:`../scale-out` says what every node needs)::

    ray start --head                       # then `ray start --address <head>:6379` on the others
    python -m benchmarks.learning --backend ray --ray-address auto --out /shared/suite
    python -m benchmarks.learning --backend ray --budget paper --gpus-per-run 1 \\
        --cells $(python -m benchmarks.learning.paper_tables --cells 1) device=cuda

This tutorial runs a one-run grid at toy size on a local Ray runtime started here. It
needs the repository checkout and Ray (``pip install "torchrl-dual[ray]"``).
"""

# %%
# A local Ray runtime
# -------------------
# Without ``--ray-address`` the suite connects to the cluster ``ray start`` runs on this
# machine, else to a runtime already started in the process, as here. One CPU: one
# recipe run at a time.

import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import ray

from benchmarks.learning import suite as learning

ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)

# %%
# Submit the grid
# ---------------
# One cell (slippery Frozen-Lake 8x8 with its slips biased counter-clockwise online), one
# variant (``iql``), one seed, at the ``smoke`` budget shrunk further by recipe overrides
# (``key=value`` arguments are passed to every run). ``--out`` holds the run directories
# (on a cluster: storage every node mounts); ``--results``, ``--docs`` and ``--figures``
# are where the JSONs, the report and its plots go (by default the repository's
# ``benchmarks/results/``, ``docs/results.md`` and ``docs/figures/``).

root = Path(tempfile.mkdtemp())
flags = [
    *("--budget", "smoke", "--cells", "frozenlake8x8_slip", "--variants", "iql", "--seeds", "0"),
    *("--backend", "ray"),
    *("--out", str(root / "out"), "--results", str(root / "results")),
    *("--docs", str(root / "results.md"), "--figures", str(root / "figures")),
    *("budget.offline_updates=10", "budget.online_frames=100", "budget.frames_per_batch=50"),
    *("budget.eval_every=50", "budget.eval_episodes=1", "budget.checkpoint_every=50"),
]
assert learning.main(flags) == 0, "a run failed: its stderr is printed above"

# %%
# What a run leaves
# -----------------
# One JSON per run: the scores over the run, the seconds and CPU-seconds of each stage,
# and the machine, commit and overrides it ran with.

result_path = root / "results" / "smoke" / "frozenlake8x8_slip" / "iql" / "seed0.json"
result = json.loads(result_path.read_text())
print(sorted(result))
for point in result["history"]:
    print(point["label"], point["frames"], round(point["normalized_score"], 1))

# %%
# The report's table for the cell (the wall and CPU minutes are this machine's):

report = (root / "results.md").read_text().splitlines()
start = next(i for i, line in enumerate(report) if line.startswith("| variant"))
print("\n".join(report[start : start + 3]))

# %%
# and its learning-curve figure:

figure = next((root / "figures").glob("*.png"))
fig, ax = plt.subplots(figsize=(7, 4.5))
ax.imshow(plt.imread(figure))
ax.axis("off")
plt.show()

# %%
# Submitting the same grid again runs nothing: every run has its JSON.

learning.main(flags)
ray.shutdown()
