"""Statistics over seeds: medians with intervals, frequencies, growth rates.

Every number a study reports comes with an interval from this module, so that the report, the
claims and the README state them the same way.

* :func:`median_interval`: the median over seeds and a 95% **percentile bootstrap** interval of
  the median. Why the percentile bootstrap: per-seed metrics (error norms, ratios, j̄) are skewed
  and sometimes discrete, so a normal-theory interval is wrong; the bootstrap needs no shape
  assumption, and its resampling RNG is seeded, so a report is reproducible bit for bit.
* :func:`frequency_interval`: "holds in k of n seeds" with a 95% **Wilson score** interval of
  the proportion (well behaved at k = 0 and k = n, unlike the Wald interval).
* :func:`growth_rate`: the geometric growth rate per iteration of a positive series (a fitted
  slope of log(value) over the last iterations) with a 95% t interval of the slope. A rate whose
  whole interval lies above 1 is growth that the noise cannot explain.

Non-finite values (a diverged seed's NaN) are dropped and counted: each result carries ``n``,
the number of values used.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

#: Bootstrap resamples; 2000 keeps the Monte Carlo error of a 95% percentile bound near 0.5%.
N_BOOTSTRAP = 2000
#: Confidence level of every interval.
LEVEL = 0.95
#: Fixed seed of the bootstrap RNG, so the same data always give the same interval.
BOOTSTRAP_SEED = 20240601


@dataclass(frozen=True)
class Interval:
    """A point estimate with a two-sided interval. ``n`` values were used (NaN ones dropped)."""

    estimate: float
    low: float
    high: float
    n: int

    def __str__(self) -> str:
        return format_interval(self)


def median_interval(values, level: float = LEVEL, n_boot: int = N_BOOTSTRAP,
                    seed: int = BOOTSTRAP_SEED) -> Interval:
    """Median of the finite ``values`` and its percentile-bootstrap interval at ``level``.

    ``values``: 1-D array-like. With no finite value the result is all NaN with ``n = 0``; with
    one value the interval collapses onto it.
    """
    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[np.isfinite(x)]
    n = x.size
    if n == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    med = float(np.median(x))
    if n == 1:
        return Interval(med, med, med, 1)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, n, size=(n_boot, n))
    boot = np.median(x[idx], axis=1)
    alpha = (1.0 - level) / 2.0
    low, high = np.quantile(boot, [alpha, 1.0 - alpha])
    return Interval(med, float(low), float(high), n)


def frequency_interval(successes: int, trials: int, level: float = LEVEL) -> Interval:
    """Proportion ``successes / trials`` with its Wilson score interval at ``level``."""
    if trials < 0 or successes < 0 or successes > trials:
        raise ValueError(f"need 0 <= successes <= trials, got {successes} of {trials}")
    if trials == 0:
        return Interval(math.nan, math.nan, math.nan, 0)
    z = _normal_quantile(0.5 + level / 2.0)
    p = successes / trials
    denom = 1.0 + z * z / trials
    centre = (p + z * z / (2.0 * trials)) / denom
    half = z * math.sqrt(p * (1.0 - p) / trials + z * z / (4.0 * trials * trials)) / denom
    return Interval(p, max(0.0, centre - half), min(1.0, centre + half), trials)


def growth_rate(series, last: int | None = None, level: float = LEVEL) -> Interval:
    """Geometric growth rate per iteration of a positive series, with a t interval.

    Fits log(series[j]) = a + b j by least squares over the last ``last`` entries (all when
    None) and returns exp(b) with the interval exp(b +- t s_b). Entries that are not finite and
    positive are dropped; fewer than 3 left gives NaN. A rate above 1 whose interval lies above
    1 means sustained growth.
    """
    y = np.asarray(series, dtype=np.float64).ravel()
    j = np.arange(y.size, dtype=np.float64)
    if last is not None:
        y, j = y[-last:], j[-last:]
    keep = np.isfinite(y) & (y > 0)
    y, j = np.log(y[keep]), j[keep]
    n = y.size
    if n < 3:
        return Interval(math.nan, math.nan, math.nan, n)
    jc = j - j.mean()
    sxx = float(jc @ jc)
    slope = float(jc @ (y - y.mean())) / sxx
    resid = y - y.mean() - slope * jc
    s_b = math.sqrt(float(resid @ resid) / (n - 2) / sxx)
    t = _t_quantile(0.5 + level / 2.0, n - 2)
    return Interval(math.exp(slope), math.exp(slope - t * s_b), math.exp(slope + t * s_b), n)


def format_interval(iv: Interval, digits: int = 3) -> str:
    """``"1.23e-05 [1.1e-05, 1.4e-05]"``; ``"-"`` when there is no value."""
    if iv.n == 0 or not math.isfinite(iv.estimate):
        return "-"
    if iv.low == iv.high == iv.estimate:
        return f"{iv.estimate:.{digits}g}"
    return f"{iv.estimate:.{digits}g} [{iv.low:.{digits}g}, {iv.high:.{digits}g}]"


@functools.lru_cache(maxsize=256)  # scipy's ppf costs ~1 ms a call; a study report asks thousands of times
def _normal_quantile(p: float) -> float:
    from scipy.stats import norm

    return float(norm.ppf(p))


@functools.lru_cache(maxsize=256)
def _t_quantile(p: float, dof: int) -> float:
    from scipy.stats import t

    return float(t.ppf(p, dof))
