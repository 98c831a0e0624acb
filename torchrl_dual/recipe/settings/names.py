"""The option names the schema accepts that belong to the library's own tables.

The library's tables (noise schedules, samplers, weightings, shifts, ...) live in
modules that import torch; the schema must not. These are their names, and
``tests/recipe/test_settings_light.py`` checks that each equals the library's table,
so a new option added there fails that test until it is named here too.
"""

from __future__ import annotations

SCHEDULES = ("cosine", "linear")
"""``torchrl_dual.diffusion.SCHEDULES``: ``planner.schedule``."""
SAMPLERS = ("ddim", "ddpm")
"""``torchrl_dual.diffusion.SAMPLERS``: ``diffuser.sampler``."""
LATENTS = ("zero", "sample")
"""``torchrl_dual.diffusion.LATENTS``: ``actor.latent``."""
UNCERTAINTIES = ("laplace", "latent")
"""``torchrl_dual.modules.dual_policy.UNCERTAINTIES``: ``laplace.uq``."""
WEIGHTINGS = ("advantage", "sac", "uniform")
"""``torchrl_dual.objectives.WEIGHTINGS``: ``actor.weighting``."""
PENALTY_LAYOUTS = ("calql", "torchrl")
"""``torchrl_dual.objectives.PENALTY_LAYOUTS``: ``critic.penalty_layout``."""
TARGET_REDUCTIONS = ("independent", "min", "mean")
"""``torchrl_dual.objectives.so2.TARGET_REDUCTIONS``: ``critic.*target_reduction``."""
FROZENLAKE_MAPS = ("4x4", "8x8")
"""``torchrl_dual.envs.FROZENLAKE_MAPS``: ``env.map_name``."""
POINTMAZE_MAZES = ("umaze", "medium", "large")
"""The keys of ``torchrl_dual.envs.POINTMAZE_IDS``: ``env.maze``."""
SHIFTS_BY_KIND = {
    "pointmaze": ("none", "rotation", "damping", "mass"),
    "frozenlake": ("none", "biased_slip", "biased_slip_cw"),
    "antmaze": ("none",),
    "locomotion": ("none", "friction", "gravity", "kinematic", "morphology"),
    "adroit": ("none",),
}
"""``torchrl_dual.envs.shift_names(kind)`` of every env kind: ``env.shift``."""
