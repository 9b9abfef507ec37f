"""Confidence intervals for summaries over runs: Wilson score intervals for proportions and
Student-t intervals for means (used by :mod:`onlinemap.reproduce` and :mod:`onlinemap.sweeps`)."""

from __future__ import annotations

import math
from statistics import NormalDist
from typing import NamedTuple

import numpy as np


class Interval(NamedTuple):
    mean: float
    low: float
    high: float


def wilson_interval(successes, trials, confidence: float = 0.95) -> tuple[np.ndarray, np.ndarray]:
    """Wilson score interval for a binomial proportion: the p with
    ``|successes / trials - p| <= z sqrt(p (1 - p) / trials)``. Vectorised; returns (low, high)."""
    k, n = np.asarray(successes, dtype=np.float64), np.asarray(trials, dtype=np.float64)
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    centre = (p + z**2 / (2 * n)) / (1 + z**2 / n)
    half = z / (1 + z**2 / n) * np.sqrt(p * (1 - p) / n + z**2 / (4 * n**2))
    return np.clip(centre - half, 0, 1), np.clip(centre + half, 0, 1)


def mean_interval(values: np.ndarray, confidence: float = 0.95, proportion: bool = False,
                  bounds: tuple[float, float] = (-math.inf, math.inf)) -> Interval:
    """Mean with a Student-t interval over the finite values; for a ``proportion`` (0/1 data)
    the Wilson score interval, which stays honest when every run agrees. NaN bounds with fewer
    than 2 values (t interval). ``bounds``: the range the mean lies in (e.g. (0, 1) for an
    error); the t interval is intersected with it, which keeps its coverage."""
    from scipy.special import stdtrit  # Student t's quantile, what scipy.stats.t.ppf returns (1 s less to import)

    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    n = len(values)
    if n == 0:
        return Interval(math.nan, math.nan, math.nan)
    mean = float(values.mean())
    if proportion:
        low, high = wilson_interval(values.sum(), n, confidence)
        return Interval(mean, float(low), float(high))
    if n < 2:
        return Interval(mean, math.nan, math.nan)
    half = stdtrit(n - 1, 0.5 + confidence / 2) * values.std(ddof=1) / math.sqrt(n)
    return Interval(mean, max(mean - half, bounds[0]), min(mean + half, bounds[1]))
