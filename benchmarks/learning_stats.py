"""The learning suite's statistics: 95 % Student-t intervals and how they are printed.

>>> mean, half = t_interval([1.0, 2.0, 3.0])  # sd 1, n 3: t(0.975, 2) / sqrt(3)
>>> round(mean, 3), round(half, 3), fmt((mean, half))
(2.0, 2.484, '2.0 ± 2.5')
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence

# Two-sided 95 % quantiles t(0.975, dof) of Student's t for dof = 1..30.
T_975 = (
    12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281,
    2.2010, 2.1788, 2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860,
    2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423,
)  # fmt: skip


def t_quantile_975(dof: int) -> float:
    """t(0.975, dof): the table for dof <= 30, else the Cornish-Fisher expansion around
    z = 1.95996 (error < 1e-4 for dof > 30)."""
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof}")
    if dof <= len(T_975):
        return T_975[dof - 1]
    z = 1.959964
    return z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)


def t_interval(values: Sequence[float]) -> tuple[float, float]:
    """(mean, half-width of the 95 % Student-t interval, n - 1 dof); half-width nan if n < 2."""
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, math.nan
    return mean, t_quantile_975(len(values) - 1) * statistics.stdev(values) / math.sqrt(len(values))


def fmt(interval: tuple[float, float]) -> str:
    mean, half = interval
    return f"{mean:.1f}" if math.isnan(half) else f"{mean:.1f} ± {half:.1f}"
