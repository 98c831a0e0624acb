"""The learning suite's variants: a name for each recipe configuration it runs (an
``algo=`` and more overrides), the groups the cells draw them from, and which overrides
only the online phase reads.

``python -m benchmarks.learning`` runs ``cells × variants × seeds`` (the cells are in
``cells.py``); adding a variant is adding an entry to :data:`VARIANTS`.
"""

from __future__ import annotations

from benchmarks.learning import reference_d3rlpy

VARIANTS: dict[str, tuple[str, ...]] = {
    "dual": ("algo=dual",),
    "iql": ("algo=iql",),
    # the reference implementation of `iql` on the same data, budget, replay and evaluator
    # (d3rlpy 2.8.1's IQL as a learner of the recipe's run: benchmarks/learning/reference_d3rlpy.py)
    "iql_d3rlpy": ("algo=iql",),
    # `iql` before issue 27's fix: TorchRL's TanhNormal actor with a state-dependent scale
    "iql_tanh_normal": ("algo=iql", "actor.distribution=tanh_normal"),
    "iql_la": ("algo=iql_la",),
    # `iql_la` before its Gauss-Newton fit of the Gaussian actor: the TanhNormal actor
    "iql_la_tanh_normal": ("algo=iql_la", "actor.distribution=tanh_normal"),
    "diffql": ("algo=diffql",),
    "diffql_la": ("algo=diffql_la",),
    "dual_no_uq": ("algo=dual", "laplace.num_samples=0"),
    # the posterior tempered (issue 29): Σ × 100, and the paper's literal Eq. 7 (the mean
    # loss's Laplace, about N times wider); both on dual's offline phase
    "dual_t100": ("algo=dual", "laplace.posterior_temperature=100"),
    "dual_tdata": ("algo=dual", "laplace.posterior_temperature=data"),
    "dual_lambda0": ("algo=dual", "exploration.shift_weight=0"),
    # IQL given DUAL's CPU time on U-maze (measured 2026-12-03 with today's code: DUAL
    # 590 CPU-s per run, IQL 301 CPU-s of which 187 for its 10000 offline updates, i.e.
    # 18.7 ms per update: +16000 updates ≈ 600 CPU-s); same online frames and UTD
    "iql_equal_time": ("algo=iql", "budget.offline_updates=26000"),
    # the same after fused Adam (issue 40), for umaze_fresh: there DUAL took 590-653 CPU-s
    # per run, IQL 310-350 at 20.7 CPU-ms per offline update, so +14000 updates ≈ 290 CPU-s;
    # a new name, so `iql_equal_time`'s runs keep their definition
    "iql_equal_time_24k": ("algo=iql", "budget.offline_updates=24000"),
    # the same once more after DUAL's fused actor (cb46f83) and IQL's one-pass losses
    # (1d13292, 1.26x): umaze_fresh's DUAL re-runs took 454-541 CPU-s (mean 505), IQL at
    # HEAD (umaze_fresh seed 5, 2026-12-06) 14.0 CPU-ms per offline update plus 90 CPU-s for
    # its evaluation and online phase, so 505 CPU-s buy about 29000 offline updates
    "iql_equal_time_29k": ("algo=iql", "budget.offline_updates=29000"),
    # IQL given DUAL's CPU time on medium_goal_long, spent online instead (its offline phase
    # is medium_goal's): measured 2026-12-03, DUAL 1130 CPU-s offline + 150 per 8000 frames,
    # IQL 630 + 90, so IQL's 1100 CPU-s after its offline phase buy ≈ 96000 frames
    "iql_equal_time_online": ("algo=iql", "budget.online_frames=96000"),
    "dual_no_planner": ("algo=dual", "actor.init=scratch"),
    "dual_no_distillation": (
        "algo=dual",
        "distillation.final_steps=8",
        "budget.distill_updates=[100,100]",
    ),
    "dual_latent_uq": ("algo=dual", "laplace.uq=latent"),
    "diffuser": ("algo=diffuser",),
    "dacer": ("algo=dacer",),
    # planner augmentation (Algorithm 1 line 14, EDIS): IQL + guided planner transitions,
    # and DUAL + the same step ("DUAL + EDIS", the paper's Fig. 4(b))
    "edis": ("algo=edis",),
    "dual_augment": ("algo=dual", "augment.kind=planner"),
    "calql": ("algo=calql",),  # Cal-QL (critic/calql), the base critic of the paper's Table 2
    # the reference implementation of `calql` (d3rlpy 2.8.1's CalQL, benchmarks/learning/reference_d3rlpy.py)
    "calql_d3rlpy": ("algo=calql",),
    "dual_calql": ("algo=dual", "critic=calql"),  # DUAL on Cal-QL's critic (Table 2)
    # SO2 + OFF2ON and DUAL on it (Table 2), at 2 critic steps per actor step online instead
    # of SO2's 10: measured (docs/benchmarks.md) an SO2 update costs ~2.5x IQL's, so
    # SO2's UTD 10 would make one run ~1.5 CPU hours at the default budget
    "so2": ("algo=so2", "critic.online_steps_per_update=2"),
    "dual_so2": ("algo=dual", "critic=so2", "replay=balanced", "critic.online_steps_per_update=2"),
    # DUAL's online settings, tuned against the default's final-score wander (docs/results.md,
    # "Budget split"): a larger offline share of each batch, or half the updates per frame
    "dual_offline_frac75": ("algo=dual", "online.offline_fraction=0.75"),
    "dual_utd025": ("algo=dual", "online.utd_ratio=0.25"),
    # λ max(d_t − d_0, 0) with d_0 the transition model's error on D_offline (beyond the
    # paper): d_t is 0.27 on the data and 0.31 online without a shift (shift_signal.py)
    "dual_shift_floor": ("algo=dual", "exploration.shift_floor=offline"),
    # Eq. 10's control (beyond the paper): λ = 0 and a constant variance v_c = 0.15, i.e.
    # λ = 0.5 times the mean d_t of DUAL's medium_goal_long runs (0.30): the same noise, with no
    # dependence on where the transition model errs
    "dual_constant_noise": (
        "algo=dual",
        "exploration.shift_weight=0",
        "exploration.extra_variance=0.15",
    ),
    # issue 39: each reference's reward transform for sparse mazes (CORL's IQL on AntMaze:
    # r - 1; Cal-QL's AntMaze scripts: 10 r - 5, with its sparse Monte-Carlo bound r_fail = -5)
    "calql_sparse": (
        "algo=calql", "env.reward_scale=10", "env.reward_shift=-5",
        "critic.sparse_failure_reward=-5",
    ),
    "calql_d3rlpy_sparse": ("algo=calql", "env.reward_scale=10", "env.reward_shift=-5"),
    # ours as d3rlpy's runs it (no sparse bound: d3rlpy has none), and the authors' AntMaze
    # Cal-QL whole (settings/references.py: + Lagrange gap 0.8, Q 256 x 4)
    "calql_sparse_no_bound": ("algo=calql", "env.reward_scale=10", "env.reward_shift=-5"),
    "calql_antmaze_preset": (
        "algo=calql", "env.reward_scale=10", "env.reward_shift=-5",
        "critic.sparse_failure_reward=-5", "critic.lagrange_gap=0.8", "critic.depth=4",
    ),
    "iql_sparse": ("algo=iql", "env.reward_shift=-1"),
    "iql_d3rlpy_sparse": ("algo=iql", "env.reward_shift=-1"),
    "dual_sparse": ("algo=dual", "env.reward_shift=-1"),
}  # fmt: skip
"""Variant name -> recipe overrides."""

SUPERSEDED: dict[str, str] = {
    "iql_tanh_normal": "`iql` on TorchRL's `TanhNormal` actor, replaced by its Gaussian actor",
    "iql_la_tanh_normal": "`iql_la` on the `TanhNormal` actor",
    "iql_equal_time_tanh_normal": "`iql_equal_time` on the `TanhNormal` actor",
    "iql_equal_time_online_tanh_normal": "`iql_equal_time_online` on the `TanhNormal` actor",
    "edis_tanh_normal": "`edis` on the `TanhNormal` actor",
    "iql_equal_time_24k": "IQL's budget at DUAL's CPU time before IQL's update got faster; "
    "`iql_equal_time_29k` replaces it",
}
"""Variants whose runs stay in ``results/`` but out of the report's tables (a later variant
replaces them; the report lists them under "Not in these tables") -> why."""

RECIPE_SCRIPT = ("recipes/o2o.py",)
"""What a run runs, after ``python``: the recipe's script."""

REFERENCE_D3RLPY = ("-m", reference_d3rlpy.MODULE)
"""d3rlpy's IQL and Cal-QL as learners of the recipe's run (``reference_d3rlpy.py``), run as
a module from the repository root."""

REFERENCE_SCRIPTS: dict[str, tuple[str, ...]] = {
    "iql_d3rlpy": REFERENCE_D3RLPY,
    "calql_d3rlpy": REFERENCE_D3RLPY,
    "iql_d3rlpy_sparse": REFERENCE_D3RLPY,
    "calql_d3rlpy_sparse": REFERENCE_D3RLPY,
}
"""Variants run by a reference implementation instead of :data:`RECIPE_SCRIPT` (what follows
``python``): it takes the same overrides and writes the same ``summary.json``."""

REFERENCE_CHECKS = ("calql_d3rlpy",)
"""Reference runs checked on one cell only (``umaze_baselines``, 3 seeds): Cal-QL's."""

IQL_VARIANTS = (
    "iql",
    "iql_equal_time",
    "iql_equal_time_24k",
    "iql_equal_time_29k",
    "iql_equal_time_online",
)
"""The IQL runs DUAL is compared with at equal steps (``iql``) and equal time (both)."""

ABLATION_VARIANTS = ("dual_no_planner", "dual_no_distillation", "dual_latent_uq")
"""The paper's other ablation rows (beyond the issue's grid)."""

CRITIC_VARIANTS = ("calql", "dual_calql", "so2", "dual_so2")
"""The paper's other critics (Table 2): Cal-QL and SO2 + OFF2ON, each alone and under DUAL."""

PAPER_BASELINES = ("diffuser", "dacer", "edis", "dual_augment", *CRITIC_VARIANTS)
"""The paper's other baselines, "DUAL + EDIS" and the other critics (beyond the issue's grid)."""

ONLINE_TUNING_VARIANTS = ("dual_offline_frac75", "dual_utd025")
"""DUAL with other online settings, on the offline phases of ``dual``'s seeds."""

NOISE_VARIANTS = ("dual_shift_floor",)
"""DUAL's noise beyond the paper, run on the umaze_20k cells."""

NOISE_CONTROLS = ("dual_constant_noise",)
"""Eq. 10's state-independent control, run where λ made a difference (Medium)."""

TEMPERATURE_VARIANTS = ("dual_t100", "dual_tdata")
"""The tempered posteriors of issue 29, next to ``dual`` and ``dual_no_uq``."""

SHIFT_VARIANTS = ("dual", "iql", "dual_lambda0")

SPARSE_REWARD_VARIANTS = (
    "calql_sparse",
    "calql_d3rlpy_sparse",
    "calql_sparse_no_bound",
    "calql_antmaze_preset",
    "iql_sparse",
    "iql_d3rlpy_sparse",
    "dual_sparse",
)
"""Each reference's sparse-maze reward transform (issue 39), on U-maze."""


# Overrides that only the online phase reads: runs differing only in these share the
# offline phase (torchrl_dual.recipe.o2o.offline_cache.ONLINE_KEYS).
ONLINE_ONLY = (
    "budget.online_frames=",
    "env.shift=",
    "env.start_avoid_cells=",
    "laplace.num_samples=",
    "laplace.uq=",
    "laplace.posterior_temperature=",
    "exploration.shift_weight=",
    "exploration.shift_floor=",
    "exploration.extra_variance=",
    "augment.",
    "replay=",
    "critic.online_steps_per_update=",
    "online.offline_fraction=",
    "online.utd_ratio=",
)


def baseline_variants() -> tuple[str, ...]:
    """The variants that are not DUAL (``algo`` other than ``dual``): what DUAL is
    compared against, in grid order.

        >>> baseline_variants()[:3]
        ('iql', 'iql_d3rlpy', 'iql_tanh_normal')
    """
    return tuple(name for name, overrides in VARIANTS.items() if overrides[0] != "algo=dual")


def dual_variants() -> dict[str, str]:
    """DUAL's ablations and settings: ``algo=dual`` with more overrides, on its own critic
    (``critic=`` variants are compared against that critic instead) -> those overrides.
    Those whose overrides are all :data:`ONLINE_ONLY` load ``dual``'s offline phase; the
    others (no planner, no distillation) train their own.

        >>> dual_variants()["dual_no_uq"], dual_variants()["dual_no_planner"]
        ('laplace.num_samples=0', 'actor.init=scratch')
    """
    return {
        name: " ".join(overrides[1:])
        for name, overrides in VARIANTS.items()
        if overrides[0] == "algo=dual"
        and len(overrides) > 1
        and not any(o.startswith("critic=") for o in overrides[1:])
    }
