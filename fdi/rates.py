"""Rates of a Monte Carlo as what they are: k of n runs, with a confidence interval.

A tune scores each fault case on a few dozen runs. 43 of 46 runs (93 %) and 46 of 46 are both
consistent with a true rate of 95 %, so a target such as "isolated in >= 95 % of runs" is judged
on the interval, not on the ratio: met when the whole interval lies on the right side of the
target, not met when it lies on the wrong side, and undecided at this many runs otherwise.

The interval is Clopper-Pearson's exact one (``scipy.stats.binomtest``): it covers the true rate
in at least ``level`` of Monte Carlos at any n, where the normal approximation fails near 0 and 1,
which is where detection and false-alarm rates live. It is conservative; a verdict it gives is
not an artefact of the approximation.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import binomtest, quantile_test

#: two-sided confidence level of the intervals: each end is a one-sided 97.5 % bound
LEVEL = 0.95
VERDICTS = ("met", "not met", "undecided")


def interval(k: int, n: int, level: float = LEVEL) -> tuple[float, float]:
    """(low, high): the exact ``level`` confidence interval of a rate seen in k of n runs
    (NaN, NaN for n = 0: nothing was measured)."""
    if n == 0:
        return math.nan, math.nan
    ci = binomtest(int(k), int(n)).proportion_ci(confidence_level=level, method="exact")
    return float(ci.low), float(ci.high)


def verdict(k: int, n: int, target: float, at_least: bool = True, level: float = LEVEL) -> str:
    """Whether k of n runs show a true rate >= ``target`` (``at_least``; a detection rate) or
    <= ``target`` (a false-alarm rate): 'met' when the whole :func:`interval` is on the target's
    side, 'not met' when it is wholly on the other side, 'undecided' otherwise (and for n = 0)."""
    if n == 0:
        return "undecided"
    low, high = interval(k, n, level)
    good, bad = (low >= target, high < target) if at_least else (high <= target, low > target)
    return "met" if good else "not met" if bad else "undecided"


def runs_to_show(target: float, level: float = LEVEL) -> int:
    """The fewest runs with no miss at all whose interval lies above ``target``: below this a
    Monte Carlo cannot show a rate of ``target`` even when every run passes. (k = n: the low end is
    ((1 - level) / 2) ** (1 / n).)"""
    return math.ceil(math.log((1.0 - level) / 2.0) / math.log(target))


def median_interval(x, level: float = LEVEL) -> tuple[float, float]:
    """(low, high): the distribution-free ``level`` confidence interval of the median of the
    samples ``x`` (order statistics, ``scipy.stats.quantile_test``); (NaN, NaN) where too few
    samples bound it (fewer than 6 at 95 %)."""
    x = np.asarray(x, dtype=float)
    x = x[np.isfinite(x)]
    if len(x) == 0:
        return math.nan, math.nan
    ci = quantile_test(x, q=float(np.median(x)), p=0.5).confidence_interval(confidence_level=level)
    return float(ci.low), float(ci.high)


def within(ci: tuple[float, float], low: float, high: float) -> str:
    """Whether a quantity with the interval ``ci`` lies within [low, high]: 'met' when the whole
    interval does, 'not met' when it lies wholly outside, 'undecided' otherwise (and for NaN)."""
    lo, hi = ci
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return "undecided"
    if low <= lo and hi <= high:
        return "met"
    return "not met" if hi < low or lo > high else "undecided"
