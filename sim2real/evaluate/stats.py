"""Small statistics for success rates and seed spreads (no scipy dependency)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

# Two-sided 95% Student-t quantiles by degrees of freedom (df > 30 uses the normal 1.96).
_T95: dict[int, float] = {
    1: 12.706,
    2: 4.303,
    3: 3.182,
    4: 2.776,
    5: 2.571,
    6: 2.447,
    7: 2.365,
    8: 2.306,
    9: 2.262,
    10: 2.228,
    15: 2.131,
    20: 2.086,
    30: 2.042,
}


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion: sane at 0% and 100%, unlike Wald's."""
    if n <= 0:
        return (0.0, 1.0)
    if not 0 <= successes <= n:
        raise ValueError(f"successes {successes} not in [0, {n}]")
    p = successes / n
    z2 = z * z
    denom = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    lo = 0.0 if successes == 0 else max(0.0, centre - half)  # exact at the ends, where
    hi = 1.0 if successes == n else min(1.0, centre + half)  # rounding would cut p itself
    return (lo, hi)


def t95(df: int) -> float:
    if df <= 0:
        return math.nan
    if df > 30:
        return 1.96
    known = [k for k in _T95 if k >= df]
    return _T95[min(known)] if df not in _T95 else _T95[df]


def mean_ci95(values: Sequence[float]) -> tuple[float, float, float]:
    """(mean, low, high) with a Student-t interval over seeds; a single value has no spread."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return (math.nan, math.nan, math.nan)
    m = float(x.mean())
    if len(x) == 1:
        return (m, m, m)
    half = t95(len(x) - 1) * float(x.std(ddof=1)) / math.sqrt(len(x))
    return (m, m - half, m + half)
