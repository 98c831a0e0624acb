"""
The recipe and its overrides
============================

The recipe runs Algorithm 1 end to end (offline data, planner, distillation, offline
actor-critic, Laplace fit, online phase with evaluations) for DUAL and its baselines. It
is a Hydra program::

    torchrl-dual env=frozenlake budget=smoke               # the console script
    python -m torchrl_dual.recipe env=frozenlake budget=smoke algo=iql
    python recipes/o2o.py env=frozenlake budget=smoke seed=3

and a library: :func:`~torchrl_dual.recipe.compose_checked` composes and validates the
same config from the same overrides, :func:`~torchrl_dual.recipe.run` runs it. This
tutorial runs DUAL on slippery Frozen-Lake at the ``smoke`` budget, shrunk further by
overrides, and plots its learning curve. The :doc:`../recipe` guide explains the run;
:doc:`../config` lists every key.
"""

# %%
# Compose a config from overrides
# -------------------------------
# ``budget=smoke`` picks a config *group* option (``budget/smoke.yaml``); ``budget.*=...``
# changes single keys. Everything is checked before any data or network is built.

import json
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
from omegaconf import OmegaConf

from torchrl_dual.recipe import CONFIG_DIR, ConfigError, compose_checked, run

out = Path(tempfile.mkdtemp())
overrides = [
    "env=frozenlake",  # slippery 4x4 Frozen-Lake, offline data at slip 3/4
    "budget=smoke",  # tiny networks and update counts: checks the plumbing
    "budget.planner_updates=30",
    "budget.offline_updates=30",
    "budget.online_frames=300",
    "budget.eval_every=100",
    "num_threads=1",
    "progress=false",  # no progress bars in the rendered output
    f"output_dir={out / 'run'}",
    f"data_cache_dir={out / 'cache'}",
]
cfg = compose_checked(CONFIG_DIR, overrides)
print(OmegaConf.to_yaml(cfg.budget))

# %%
# A mistake is one line naming the key, the value and what is allowed (the command line
# prints it and exits with code 2):

for bad in (["budget.onlin_frames=300"], ["algo=dqn"], ["budget.online_frames=-5"]):
    try:
        compose_checked(CONFIG_DIR, bad)
    except ConfigError as error:
        print(f"{bad[0]!r:30} -> {error}")

# %%
# Run it
# ------
# :func:`~torchrl_dual.recipe.run` validates the config and runs the ``algo`` entry's
# learner through the offline and the online phase. The run directory holds the metrics
# (CSV logger by default), ``summary.json``, a checkpoint (``resume=true`` continues an
# interrupted run) and ``learning_curve.png``.

result = run(cfg)
print(sorted(path.name for path in (out / "run").iterdir()))

# %%
# The learning curve
# ------------------
# ``summary.json`` records every evaluation: the normalized score after the offline phase
# (at 0 online frames) and during the online phase, where the env's slip probability has
# shifted from 1/4 to 1/3. At this budget the numbers say nothing about DUAL; the
# ``default`` and ``paper`` budgets are for results (:doc:`../results`).

summary = json.loads((out / "run" / "summary.json").read_text())
frames = [point["frames"] for point in summary["history"]]
scores = [point["normalized_score"] for point in summary["history"]]
fig, ax = plt.subplots(figsize=(6, 3.5))
ax.plot(frames, scores, marker="o")
ax.set(
    xlabel="online frames",
    ylabel="normalized score",
    title=f"{summary['algo']} on {summary['env']}, budget={summary['budget']}",
)
fig.tight_layout()
plt.show()

# %%
# DUAL's exploration signals
# --------------------------
# For DUAL the summary also records what the acting policy wrote into each collected
# batch (Eq. 9-10): the epistemic standard deviation of the Laplace ensemble and the
# shift distance ``d_t``.

for signals in summary["online_signals"]:
    print({key: round(value, 3) for key, value in signals.items()})

# %%
# Other algorithms and tasks are overrides too: ``algo=iql`` (or ``iql_la``, ``diffql``,
# ``diffuser``, ``dacer``, ``edis``, ``calql``, ``so2``), ``critic=calql``,
# ``env=pointmaze_umaze``, ``env.shift=biased_slip``, ``replay=balanced``,
# ``logger=tensorboard``, ``collector=multi_sync``; ``torchrl-dual --cfg job`` prints the
# composed config.
