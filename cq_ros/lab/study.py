"""The arithmetic of a study over units (a unit: one map and one run, the same for every learner): means with
95% t intervals, paired differences between learners on the same units, bootstrap intervals of ratios of
means, the every-AGV-home rate and the makespan against the planner's. benchmarks/bench_delays.py prints its
tables with these; tests/test_study.py checks them on data whose answers are known.

Intervals are Student t with n - 1 degrees of freedom (cq_ros.student_t: no scipy); a ratio's is the percentile
interval of the ratio of means over units resampled with replacement, the same units for numerator and
denominator (they are paired), from a seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from ..student_t import upper_quantile

LEVEL = 0.95
RESAMPLES = 10_000


class Interval(NamedTuple):
    mean: float
    low: float
    high: float

    @property
    def half(self) -> float:
        return (self.high - self.low) / 2

    def show(self, digits: int) -> str:
        """'0.094 ± 0.080'; a single unit has no spread, and shows its mean alone."""
        if math.isnan(self.half):
            return f"{self.mean:.{digits}f}"
        return f"{self.mean:.{digits}f} ± {self.half:.{digits}f}"


def mean_interval(values: Sequence[float], level: float = LEVEL) -> Interval:
    """The mean over units and its `level` t interval (n - 1 df; NaN bounds for fewer than two units)."""
    x = np.asarray(values, dtype=float)
    if x.size == 0:
        raise ValueError("an interval needs at least one unit")
    mean = float(x.mean())
    if x.size < 2:
        return Interval(mean, math.nan, math.nan)
    half = upper_quantile((1 - level) / 2, x.size - 1) * float(x.std(ddof=1)) / math.sqrt(x.size)
    return Interval(mean, mean - half, mean + half)


def paired_difference(a: Sequence[float], b: Sequence[float], level: float = LEVEL) -> Interval:
    """a - b unit by unit (the same maps, the same runs), with its t interval: what the units share cancels."""
    if len(a) != len(b):
        raise ValueError(f"paired values need the same units: {len(a)} against {len(b)}")
    return mean_interval(np.asarray(a, dtype=float) - np.asarray(b, dtype=float), level)


def ratio_interval(numerator: Sequence[float], denominator: Sequence[float], seed: int, level: float = LEVEL,
                   resamples: int = RESAMPLES) -> Interval:
    """mean(numerator) / mean(denominator) and its bootstrap percentile interval: units resampled with
    replacement (the same draw for both, since unit i of each is the same map and run) from `seed`. A resample
    whose denominator is 0 gives an infinite ratio (or NaN where both are 0, counted as infinite)."""
    num, den = np.asarray(numerator, dtype=float), np.asarray(denominator, dtype=float)
    if num.size != den.size or num.size == 0:
        raise ValueError(f"a ratio needs the same units, at least one: {num.size} against {den.size}")
    draws = np.random.default_rng(seed).integers(0, num.size, size=(resamples, num.size))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratios = num[draws].mean(axis=1) / den[draws].mean(axis=1)
        point = float(num.mean() / den.mean()) if den.mean() else math.inf
    ratios = np.where(np.isnan(ratios), np.inf, ratios)
    tail = (1 - level) / 2
    low, high = np.quantile(ratios, [tail, 1 - tail], method="inverted_cdf")
    return Interval(point, float(low), float(high))


def home_rate(truncated: Sequence[float]) -> float:
    """The share of episodes in which every AGV reached its goal (the step cap did not end the episode)."""
    t = np.asarray(truncated, dtype=float)
    return float((t == 0).mean())


def makespan_ratio(makespans: Sequence[float], planner: Sequence[float], level: float = LEVEL) -> Interval:
    """Each unit's mean greedy makespan over the planner's executed makespan on the same map and delays, with
    the t interval of those ratios over units."""
    if len(makespans) != len(planner):
        raise ValueError(f"makespans need the same units: {len(makespans)} against {len(planner)}")
    return mean_interval(np.asarray(makespans, dtype=float) / np.asarray(planner, dtype=float), level)
