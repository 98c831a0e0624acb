"""Env-side transforms of torchrl-dual."""

from torchrl_dual.transforms.shift_distance import ShiftDistance

__all__ = ["ShiftDistance"]
