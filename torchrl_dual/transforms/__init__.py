"""Env-side transforms of torchrl-dual."""

from torchrl_dual.transforms.previous_transition import PreviousTransition

__all__ = ["PreviousTransition"]
