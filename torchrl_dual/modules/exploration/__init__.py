"""Exploration on the policy side: the shift-aware variance of Eq. 10."""

from torchrl_dual.modules.exploration.shift_aware_noise import ShiftAwareNoise

__all__ = ["ShiftAwareNoise"]
