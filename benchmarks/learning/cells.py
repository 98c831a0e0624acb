"""The learning suite's cells (the env settings it runs, each with its variants and
seeds) and its runs.

``python -m benchmarks.learning`` runs ``cells × variants × seeds`` from :data:`CELLS` and
the variants of ``variants.py``; adding a cell is adding an entry here.
"""

from __future__ import annotations

from dataclasses import dataclass

from benchmarks.learning.variants import (
    ABLATION_VARIANTS,
    CRITIC_VARIANTS,
    NOISE_CONTROLS,
    NOISE_VARIANTS,
    ONLINE_ONLY,
    ONLINE_TUNING_VARIANTS,
    PAPER_BASELINES,
    REFERENCE_CHECKS,
    SHIFT_VARIANTS,
    SPARSE_REWARD_VARIANTS,
    TEMPERATURE_VARIANTS,
    VARIANTS,
)

MEDIUM_EXPLORE_ROOM = "[[4,6],[5,6],[6,5],[6,6]]"
"""Medium's bottom-right dead end, which ``medium_explore``'s offline data never enter."""

MEDIUM_EXPLORE = (
    "env=pointmaze_medium", "env.goal_cell=[6,6]", f"env.data_avoid_cells={MEDIUM_EXPLORE_ROOM}",
    "budget.offline_updates=40000", "budget.online_frames=32000",
)  # fmt: skip
"""Issue 29's exploration task: Medium's goal (6, 6) in the dead end the data never enter."""


@dataclass(frozen=True)
class Cell:
    """One environment setting of the grid: its overrides, variants and seed count."""

    overrides: tuple[str, ...]
    variants: tuple[str, ...]
    seeds: int
    about: str
    reference: str | None = None
    """The cell whose ``dual`` runs this cell's DUAL variants pair with (same overrides);
    ``None``: :func:`dual_cells` picks itself or the first such cell."""
    retired: str = ""
    """Why the cell is no longer run (empty: it is): its finished runs stay in the report,
    and the suite queues none of its runs unless ``--cells`` names it."""
    more_seeds: tuple[tuple[str, int], ...] = ()
    """``(variant, seeds)`` for variants run at more seeds than :attr:`seeds` (a pair
    whose difference 5 seeds left undecided)."""
    dual_variant: str = "dual"
    """The DUAL variant this cell's baselines are set against in the report's "DUAL
    against every baseline" table: a cell whose baselines change their reward or critic
    settings (``umaze_sparse``) pairs them with its DUAL run under the same settings."""
    first_seed: int = 0
    """The first seed the cell runs: a cell of fresh seeds (no tuning saw them) starts past
    the seeds its twin cell used."""

    def seeds_of(self, variant: str) -> int:
        """How many seeds ``variant`` runs in this cell."""
        return dict(self.more_seeds).get(variant, self.seeds)

    def seed_range(self, variant: str) -> range:
        """The seeds ``variant`` runs in this cell.

        Examples:
            >>> list(Cell((), ("a",), 3, "", first_seed=5).seed_range("a"))
            [5, 6, 7]
        """
        return range(self.first_seed, self.first_seed + self.seeds_of(variant))


CELLS: dict[str, Cell] = {
    "umaze": Cell(
        ("env=pointmaze_umaze",),
        tuple(
            v for v in VARIANTS
            if v not in (*ABLATION_VARIANTS, *PAPER_BASELINES, *ONLINE_TUNING_VARIANTS,
                         *NOISE_VARIANTS, *NOISE_CONTROLS, *TEMPERATURE_VARIANTS,
                         "iql_equal_time_online", "iql_equal_time_24k", "iql_equal_time_29k",
                         *SPARSE_REWARD_VARIANTS,
                         *REFERENCE_CHECKS)
        ), 5,
        "PointMaze U-maze",
    ),
    # DUAL and IQL with twice the offline actor-critic updates (DUAL: ≈ 1.4x the CPU time of
    # its `default` run), and DUAL's noise floor on those offline phases
    "umaze_20k": Cell(
        ("env=pointmaze_umaze", "budget.offline_updates=20000"), ("dual", "iql", *NOISE_VARIANTS),
        5, "PointMaze U-maze, 20000 offline actor-critic updates (`default`: 10000)",
    ),
    # the shift-aware noise with and without its floor d_0, on umaze_20k's offline phases
    "umaze_20k_rotation": Cell(
        ("env=pointmaze_umaze", "budget.offline_updates=20000", "env.shift=rotation"),
        ("dual", "dual_lambda0", *NOISE_VARIANTS), 3,
        "U-maze with 20000 offline updates, online actions rotated by 60°: λ = 0.5, λ = 0 "
        "and the floor d_0",
    ),
    # issue 29: the tempered posteriors on U-maze's DUAL offline phases
    "umaze_temperature": Cell(
        ("env=pointmaze_umaze",), TEMPERATURE_VARIANTS, 5,
        "PointMaze U-maze: DUAL's posterior × 100 and the mean loss's (`data`)",
        reference="umaze",
    ),
    "medium_explore": Cell(
        MEDIUM_EXPLORE, ("dual", "dual_no_uq", *TEMPERATURE_VARIANTS, "iql", "dual_lambda0"), 5,
        "PointMaze Medium, goal (6, 6) in the dead end the data never enter, 40000 offline "
        "updates, 32000 online frames",
        more_seeds=(("dual_tdata", 7), ("dual_no_uq", 7)),  # T = data − no-UQ ≈ at 5 seeds
        retired="its online and evaluation episodes started in the dead end too (3 of the 25 "
        "start cells, one or two moves from the goal: about 12 % of episodes), so reaching the "
        "reward did not need exploring into it; `medium_explore_v2` starts outside it",
    ),
    # issue 41: no episode starts in the dead end (an online key: the same offline phases)
    "medium_explore_v2": Cell(
        (*MEDIUM_EXPLORE, f"env.start_avoid_cells={MEDIUM_EXPLORE_ROOM}"),
        ("dual", "dual_tdata", "dual_no_uq", "iql"), 7,
        "PointMaze Medium, goal (6, 6) in the dead end the data never enter and no episode "
        "starts in, 40000 offline updates, 32000 online frames",
    ),
    # issue 39: does Cal-QL stop failing on U-maze with its reference's 10 r - 5 (and with
    # it the sparse Monte-Carlo bound)? The others with CORL's r - 1, as on AntMaze
    "umaze_sparse": Cell(
        ("env=pointmaze_umaze",), SPARSE_REWARD_VARIANTS, 3,
        "PointMaze U-maze, each reference's sparse-maze reward transform (Cal-QL 10 r − 5, "
        "IQL and DUAL r − 1)",
        dual_variant="dual_sparse",
    ),
    "umaze_online": Cell(
        ("env=pointmaze_umaze",), ONLINE_TUNING_VARIANTS, 5,
        "PointMaze U-maze: DUAL with offline share 0.75 or UTD 0.25 online (`dual`: 0.5 and 0.5)",
    ),
    # the README's U-maze comparison on seeds 5-14, which no tuning saw (DUAL's budget split
    # was chosen on `umaze` seeds 0-2): its four shown variants ran seeds 5-9 in one sitting
    # and seeds 10-14 in a second, on one host (the retired `iql_equal_time_24k`, seeds 5-9
    # only, on another host). Seeds 10-14 were added after seeds 5-9 left our IQL against
    # d3rlpy's undecided on the final score: a sequential decision (docs/results.md)
    "umaze_fresh": Cell(
        ("env=pointmaze_umaze",),
        ("dual", "iql", "iql_d3rlpy", "iql_equal_time_24k", "iql_equal_time_29k"), 5,
        "PointMaze U-maze, fresh seeds 5-14 (no tuning saw them), on one machine",
        first_seed=5,
        more_seeds=(("dual", 10), ("iql", 10), ("iql_d3rlpy", 10), ("iql_equal_time_29k", 10)),
    ),
    # its own `dual` runs: the online-only ablations (latent UQ, and DUAL + EDIS below) ran
    # on another machine than `umaze`'s (docs/results.md), so they pair with these, which
    # share their offline phase
    "umaze_ablations": Cell(
        ("env=pointmaze_umaze",), ("dual", *ABLATION_VARIANTS), 3,
        "PointMaze U-maze: w/o planner, w/o distillation (N = 8), latent UQ",
    ),
    "umaze_baselines": Cell(
        ("env=pointmaze_umaze",), (*PAPER_BASELINES, *REFERENCE_CHECKS), 3,
        "PointMaze U-maze: Diffuser, DACER, EDIS (IQL + planner augmentation), DUAL + EDIS, "
        "Cal-QL and SO2 + OFF2ON, each alone and under DUAL",
        reference="umaze_ablations",
    ),
    "umaze_rotation": Cell(
        ("env=pointmaze_umaze", "env.shift=rotation"), (*SHIFT_VARIANTS, *CRITIC_VARIANTS), 3,
        "U-maze, online actions rotated by `env.shift_angle` (60°)",
    ),
    # umaze_rotation's shift-aware claim again, whole: DUAL, λ = 0 and IQL, seeds 0-4, run
    # together on one host and one commit (its runs of record crossed commits and dates)
    "umaze_rotation_onehost": Cell(
        ("env=pointmaze_umaze", "env.shift=rotation"), ("dual", "dual_lambda0", "iql"), 5,
        "umaze_rotation's DUAL, λ = 0 and IQL again, seeds 0-4, one host and one commit",
    ),
    # the same claim on fresh seeds 5-9, which no tuning saw, on another host than the
    # seeds 0-4 of `umaze_rotation_onehost` (whose CPU rounds differently)
    "umaze_rotation_fresh": Cell(
        ("env=pointmaze_umaze", "env.shift=rotation"), ("dual", "dual_lambda0", "iql"), 5,
        "umaze_rotation's DUAL, λ = 0 and IQL on fresh seeds 5-9, one host and one commit",
        first_seed=5,
    ),
    "umaze_damping": Cell(
        ("env=pointmaze_umaze", "env.shift=damping"), SHIFT_VARIANTS, 3,
        "U-maze, online damping × 150",
    ),
    "umaze_mass": Cell(
        ("env=pointmaze_umaze", "env.shift=mass"), SHIFT_VARIANTS, 3, "U-maze, online mass × 20"
    ),
    "medium": Cell(
        ("env=pointmaze_medium",), SHIFT_VARIANTS, 3, "PointMaze Medium",
        retired="a new goal cell every episode (a goal-conditioned task): at 10000 and 40000 "
        "offline updates nobody scores above 3; `medium_goal` and `medium_goal_long` replace it",
    ),
    # Medium as D4RL maze2d poses it (one goal cell, random starts) with 4x the offline
    # updates: `medium` (a random goal per episode, 10000 updates) leaves every method at 0
    "medium_goal": Cell(
        ("env=pointmaze_medium", "env.goal_cell=[6,6]", "budget.offline_updates=40000"),
        SHIFT_VARIANTS, 3,
        "PointMaze Medium, goal fixed in cell (6, 6), 40000 offline actor-critic updates",
    ),
    # the same offline phases (budget.online_frames is an online key) with 4x the online
    # frames: DUAL's medium_goal curve still climbs at 8000 frames (13 episodes)
    "medium_goal_long": Cell(
        (
            "env=pointmaze_medium", "env.goal_cell=[6,6]", "budget.offline_updates=40000",
            "budget.online_frames=32000",
        ),
        (*SHIFT_VARIANTS, "iql_equal_time_online", *NOISE_CONTROLS), 3,
        "PointMaze Medium, goal (6, 6), 40000 offline updates, 32000 online frames "
        "(`default`: 8000)",
    ),
    # issue 41: medium_goal_long's DUAL ran on the Intel Xeon (12-03), its IQL on the AMD EPYC
    # (12-04); the pair again on one machine (AMD EPYC): IQL on the code after fused Adam,
    # DUAL re-run on its fused actor (cb46f83) the same evening
    "medium_goal_onehost": Cell(
        (
            "env=pointmaze_medium", "env.goal_cell=[6,6]", "budget.offline_updates=40000",
            "budget.online_frames=32000",
        ),
        ("dual", "iql"), 3,
        "medium_goal_long's DUAL and IQL again, on one machine (AMD EPYC)",
    ),
    "frozenlake8x8_slip": Cell(
        ("env=frozenlake", "env.map_name=8x8", "env.shift=biased_slip"), SHIFT_VARIANTS, 3,
        "Frozen-Lake 8x8, slips biased counter-clockwise online",
    ),
}  # fmt: skip
"""Cell name -> :class:`Cell` (the issue's grid)."""

PAPER_SEEDS = 5
"""The paper's seeds per cell (Tables 1-3)."""


def paper_cells() -> dict[str, Cell]:
    """The cells of the paper's Tables 1-3 (``paper_tables.py``), one per row
    that runs on Minari data, with the variants of its columns. They need the downloaded
    data sets and are meant for ``--budget paper`` on GPUs: the suite queues them only when
    ``--cells`` names them (:func:`active_cells` leaves them out).

        >>> paper_cells()["t1_antmaze_umaze"].overrides
        ('env=antmaze', 'env.dataset=umaze')
    """
    from benchmarks.learning.paper_tables import runnable_rows

    return {
        row.cell: Cell(
            row.overrides, row.variants, PAPER_SEEDS, f"the paper's Table {row.table}: `{row.row}`"
        )
        for row in runnable_rows()
    }


def cell_of(name: str) -> Cell:
    """A cell of :data:`CELLS` or of :func:`paper_cells`, by name."""
    return CELLS[name] if name in CELLS else paper_cells()[name]


def active_cells() -> list[str]:
    """The cells the suite runs by default: all but the :attr:`Cell.retired` ones.

    >>> "medium" in active_cells(), "medium_goal" in active_cells()
    (False, True)
    """
    return [name for name, cell in CELLS.items() if not cell.retired]


def baseline_duals() -> dict[str, tuple[str, str]]:
    """Cell -> ``(cell, variant)`` of the DUAL runs its baselines are set against: the
    cell's own :attr:`Cell.dual_variant` when it is not ``dual``, else :func:`dual_cells`'
    cell and its ``dual``.

        >>> baseline_duals()["umaze_sparse"], baseline_duals()["umaze_baselines"]
        (('umaze_sparse', 'dual_sparse'), ('umaze_ablations', 'dual'))
    """
    out = {name: (reference, "dual") for name, reference in dual_cells().items()}
    for name, cell in CELLS.items():
        if cell.dual_variant != "dual":
            if cell.dual_variant not in cell.variants:
                raise ValueError(
                    f"cell {name!r}: its dual_variant {cell.dual_variant!r} is not one of its "
                    "variants"
                )
            out[name] = (name, cell.dual_variant)
    return out


def dual_cells() -> dict[str, str]:
    """Cell -> the cell whose ``dual`` runs its DUAL variants pair with: its
    :attr:`Cell.reference` when set, else itself when it runs ``dual``, else the first cell
    with the same overrides that does (cells with neither are left out). Both share the
    offline phase, so the pair differs only online.

        >>> dual_cells()["umaze_online"], dual_cells()["umaze_baselines"]
        ('umaze', 'umaze_ablations')
    """
    with_dual = [name for name, cell in CELLS.items() if "dual" in cell.variants]
    out = {}
    for name, cell in CELLS.items():
        partners = [n for n in with_dual if CELLS[n].overrides == cell.overrides]
        if cell.reference is not None:
            if cell.reference not in partners:
                raise ValueError(
                    f"cell {name!r}: its reference {cell.reference!r} must run `dual` with the "
                    "same overrides"
                )
            out[name] = cell.reference
        elif partners:
            out[name] = name if name in partners else partners[0]
    return out


@dataclass(frozen=True)
class Run:
    cell: str
    variant: str
    seed: int
    overrides: tuple[str, ...]  # cell + variant overrides

    def name(self) -> str:
        return f"{self.cell}/{self.variant}/seed{self.seed}"

    def sharing_key(self) -> tuple:
        """Equal for runs that compute the same offline phase."""
        return (tuple(o for o in self.overrides if not o.startswith(ONLINE_ONLY)), self.seed)
