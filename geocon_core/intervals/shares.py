"""Shares: the Wilson score interval of a proportion ``k / n`` (:func:`wilson_interval`), the
interval of R's ``prop.test(k, n, correct = FALSE)``; it stays inside [0, 1] and is not empty at
0 / n or n / n."""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

__all__ = ["CONFIDENCE", "Interval", "wilson_interval"]

CONFIDENCE = 0.95
"""The coverage of every interval unless told otherwise."""
_NAN = float("nan")


@dataclass(frozen=True)
class Interval:
    """An estimate with its (95%) interval and the number of units (clips or scenes) behind it."""

    estimate: float
    low: float
    high: float
    n: int


def wilson_interval(successes: int, n: int, *, confidence: float = CONFIDENCE) -> Interval:
    """Wilson score interval for ``successes`` out of ``n``; all NaN when ``n == 0``."""
    if n == 0:
        return Interval(_NAN, _NAN, _NAN, 0)
    if not 0 <= successes <= n:
        raise ValueError(f"successes must be in [0, n], got {successes} of {n}")
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    low = 0.0 if successes == 0 else max(0.0, centre - half)  # exactly 0 and 1 at the ends, not 1 - 1e-16
    high = 1.0 if successes == n else min(1.0, centre + half)
    return Interval(p, low, high, n)
