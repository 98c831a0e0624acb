"""The learning suite's statistics: Student-t intervals, the equivalence test of a paired
difference (TOST) and how they are printed.

>>> mean, half = t_interval([1.0, 2.0, 3.0])  # sd 1, n 3: t(0.975, 2) / sqrt(3)
>>> round(mean, 3), round(half, 3), fmt((mean, half))
(2.0, 2.484, '2.0 ± 2.5')
>>> test = equivalence([1.0, 2.0, 3.0], margin=5.0)  # 2 ± t(0.95, 2) / sqrt(3) = 2 ± 1.686
>>> round(test.low, 3), round(test.high, 3), test.equivalent, test.text()
(0.314, 3.686, True, 'yes [+0.3, +3.7]')
>>> equivalence([1.0, 2.0, 3.0], margin=3.5).text()  # 3.686 > 3.5
'no [+0.3, +3.7]'
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Sequence
from typing import NamedTuple

# Two-sided 95 % quantiles t(0.975, dof) of Student's t for dof = 1..30.
T_975 = (
    12.7062, 4.3027, 3.1824, 2.7764, 2.5706, 2.4469, 2.3646, 2.3060, 2.2622, 2.2281,
    2.2010, 2.1788, 2.1604, 2.1448, 2.1314, 2.1199, 2.1098, 2.1009, 2.0930, 2.0860,
    2.0796, 2.0739, 2.0687, 2.0639, 2.0595, 2.0555, 2.0518, 2.0484, 2.0452, 2.0423,
)  # fmt: skip

# One-sided 95 % quantiles t(0.95, dof) for dof = 1..30: the two-sided 90 % interval's,
# which decides the two one-sided tests of :func:`equivalence` at α = 0.05.
T_95 = (
    6.3138, 2.9200, 2.3534, 2.1318, 2.0150, 1.9432, 1.8946, 1.8595, 1.8331, 1.8125,
    1.7959, 1.7823, 1.7709, 1.7613, 1.7531, 1.7459, 1.7396, 1.7341, 1.7291, 1.7247,
    1.7207, 1.7171, 1.7139, 1.7109, 1.7081, 1.7056, 1.7033, 1.7011, 1.6991, 1.6973,
)  # fmt: skip

# probability -> (the table for dof = 1..30, the standard normal quantile z_p)
_QUANTILES = {0.975: (T_975, 1.959964), 0.95: (T_95, 1.644854)}

EQUIVALENCE_MARGIN = 10.0
"""The margin m of the equivalence test, in normalized-score points: two methods are
"equivalent within ±m" when the 90 % interval of their paired difference lies inside
(−m, m). Why 10: the report's "Paired comparisons" paragraph (:mod:`benchmarks.learning.pairs`)."""


def t_quantile(p: float, dof: int) -> float:
    """t(p, dof) for p in {0.975, 0.95}: the table for dof <= 30, else the Cornish-Fisher
    expansion around the normal quantile z_p (error < 1e-4 for dof > 30)."""
    if p not in _QUANTILES:
        raise ValueError(f"p must be one of {sorted(_QUANTILES)}, got {p}")
    if dof < 1:
        raise ValueError(f"dof must be >= 1, got {dof}")
    table, z = _QUANTILES[p]
    if dof <= len(table):
        return table[dof - 1]
    return z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)


def t_quantile_975(dof: int) -> float:
    """t(0.975, dof), the quantile of the suite's 95 % intervals (:func:`t_quantile`)."""
    return t_quantile(0.975, dof)


def t_interval(values: Sequence[float], level: float = 0.95) -> tuple[float, float]:
    """(mean, half-width of the two-sided Student-t interval at ``level``, 0.95 or 0.90,
    n - 1 dof); half-width nan if n < 2."""
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, math.nan
    q = t_quantile(round(1 - (1 - level) / 2, 6), len(values) - 1)
    return mean, q * statistics.stdev(values) / math.sqrt(len(values))


class Equivalence(NamedTuple):
    """The equivalence test (TOST) of paired differences against ``±margin``."""

    low: float
    """Lower end of the differences' 90 % t interval (nan for n < 2)."""
    high: float
    """Upper end of that interval."""
    margin: float
    equivalent: bool | None
    """Both one-sided tests reject at α = 0.05, i.e. ``-margin < low`` and
    ``high < margin``; ``None`` for n < 2."""

    def text(self) -> str:
        """``yes [low, high]`` / ``no [low, high]`` (the 90 % interval, one decimal, two
        where one decimal would print a bound as ±margin); ``?`` for n < 2.

        >>> Equivalence(-9.96, 4.8, 10.0, True).text()
        'yes [-9.96, +4.80]'
        """
        if self.equivalent is None:
            return "?"
        bounds = (self.low, self.high)
        digits = 2 if any(abs(round(b, 1)) == self.margin for b in bounds) else 1
        low, high = (f"{b:+.{digits}f}" for b in bounds)
        return f"{'yes' if self.equivalent else 'no'} [{low}, {high}]"


def equivalence(diffs: Sequence[float], margin: float = EQUIVALENCE_MARGIN) -> Equivalence:
    """TOST at α = 0.05 of the mean of the paired differences ``diffs``: H₀ is
    |mean| >= ``margin``; it is rejected (equivalent within ±margin) when both one-sided
    t tests reject at 5 %, which is when the two-sided 90 % t interval (n - 1 dof) lies
    inside (−margin, margin). "Not equivalent" only means equivalence is not shown; fewer
    than 2 differences give no verdict (``None``)."""
    if len(diffs) < 2:
        return Equivalence(math.nan, math.nan, margin, None)
    mean, half = t_interval(diffs, level=0.90)
    low, high = mean - half, mean + half
    return Equivalence(low, high, margin, -margin < low and high < margin)


def fmt(interval: tuple[float, float]) -> str:
    """``mean ± half`` with one decimal, or the mean alone without an interval."""
    mean, half = interval
    return f"{mean:.1f}" if math.isnan(half) else f"{mean:.1f} ± {half:.1f}"
