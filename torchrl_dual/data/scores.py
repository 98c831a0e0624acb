"""D4RL-style normalized scores."""

from __future__ import annotations

import math
from typing import TypeVar

import numpy as np
import torch

ReturnsT = TypeVar("ReturnsT", float, np.ndarray, torch.Tensor)


def normalized_score(returns: ReturnsT, random_return: float, expert_return: float) -> ReturnsT:
    """Maps returns to ``100 * (R - R_random) / (R_expert - R_random)``.

    0 is the random policy's average return and 100 the reference (expert or
    controller) policy's; values outside ``[0, 100]`` are kept.

    Args:
        returns (float, np.ndarray or torch.Tensor): one or many episode returns; the
            output has the same type (and shape).
        random_return (float): reference return of a random policy (D4RL ``ref_min_score``).
        expert_return (float): reference return of an expert (D4RL ``ref_max_score``).

    Raises:
        ValueError: if a reference is not a finite number, if
            ``expert_return <= random_return`` (swapped or degenerate references), or if
            ``returns`` has NaN/inf entries.

    Examples:
        >>> normalized_score(150.0, random_return=0.0, expert_return=200.0)
        75.0
        >>> normalized_score(np.array([0.0, 200.0]), 0.0, 200.0)
        array([  0., 100.])
    """
    refs = {"random_return": random_return, "expert_return": expert_return}
    for name, value in refs.items():
        if isinstance(value, bool) or not isinstance(value, (int, float, np.number)):
            raise ValueError(
                f"{name} must be a real number, got {type(value).__name__}: {value!r}."
            )
        if not math.isfinite(float(value)):
            raise ValueError(f"{name} must be finite, got {value}.")
    lo, hi = float(random_return), float(expert_return)
    if hi <= lo:
        raise ValueError(
            f"expert_return ({hi}) must be greater than random_return ({lo}); "
            "check that the two references are not swapped or identical."
        )
    if isinstance(returns, torch.Tensor):
        if not torch.isfinite(returns).all():
            raise ValueError(
                f"returns has {int((~torch.isfinite(returns)).sum())} NaN/inf entries."
            )
        return 100.0 * (returns - lo) / (hi - lo)
    if isinstance(returns, np.ndarray):
        if not np.isfinite(returns).all():
            raise ValueError(f"returns has {int((~np.isfinite(returns)).sum())} NaN/inf entries.")
        return 100.0 * (returns - lo) / (hi - lo)
    if isinstance(returns, bool) or not isinstance(returns, (int, float, np.number)):
        raise ValueError(
            f"returns must be a number, a numpy array or a tensor, got {type(returns).__name__}."
        )
    if not math.isfinite(float(returns)):
        raise ValueError(f"returns must be finite, got {returns}.")
    return 100.0 * (float(returns) - lo) / (hi - lo)
