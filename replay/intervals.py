"""Confidence intervals for replay scores: Wilson intervals for accuracies, Newcombe's
paired interval for the lift of the library over a baseline on the same events.

Both are closed forms (no resampling), so the same replay always prints the same
intervals. Steps of one log are not independent (a learned pattern is right many times
in a row), so the intervals are on the narrow side for long runs of one behaviour; they
still show at once that 31 events cannot tell 87 % from 95 %.
"""

from __future__ import annotations

import math

Z95 = 1.959963984540054
"""The two-sided 95 % normal quantile."""


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a proportion ``successes / n``; ``(nan, nan)`` when ``n == 0``."""
    if n <= 0:
        return math.nan, math.nan
    p = successes / n
    denominator = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def paired_difference(a_right: int, b_right: int, only_a: int, only_b: int, n: int,
                      z: float = Z95) -> tuple[float, float, float]:
    """``(difference, low, high)`` of two accuracies measured on the same ``n`` events.

    Newcombe's hybrid score interval for paired proportions (method 10 of Newcombe 1998,
    *Statistics in Medicine* 17:2635): ``a_right`` and ``b_right`` events were right for
    each predictor, ``only_a`` right for the first only, ``only_b`` for the second only.
    ``(nan, nan, nan)`` when ``n == 0``.
    """
    if n <= 0:
        return math.nan, math.nan, math.nan
    both = a_right - only_a
    neither = n - both - only_a - only_b
    p1, p2 = a_right / n, b_right / n
    l1, u1 = wilson(a_right, n, z)
    l2, u2 = wilson(b_right, n, z)
    phi = _phi(both, only_a, only_b, neither)
    delta = math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    epsilon = math.sqrt(max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    difference = p1 - p2
    return difference, max(-1.0, difference - delta), min(1.0, difference + epsilon)


def _phi(a: int, b: int, c: int, d: int) -> float:
    """The correlation of the paired outcomes (0 when a margin is empty)."""
    denominator = (a + b) * (c + d) * (a + c) * (b + d)
    return (a * d - b * c) / math.sqrt(denominator) if denominator > 0 else 0.0
