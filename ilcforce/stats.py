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
  slope of log(value) over the last iterations, with a step where the plant changes) with a 95% t
  interval of the slope. A rate whose whole interval lies above 1 is growth that the noise cannot
  explain.

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


def growth_rate(series, last: int | None = None, level: float = LEVEL, *, iterations=None,
                shift_at: int | None = None) -> Interval:
    """Geometric growth rate per iteration of a positive series, with a t interval.

    Fits log(series[i]) = a + b j_i (+ c [j_i >= shift_at]) by least squares over the last ``last``
    entries (all when None) and returns exp(b) with the interval exp(b +- t s_b), t from Student's t
    with n - (number of coefficients) degrees of freedom. ``iterations`` gives each entry's
    iteration j_i (0, 1, 2, ... when None; the window may have a gap). ``shift_at``: a change of the
    plant at that iteration moves the level, not the trend, so the fit carries a step there (used
    only when at least two entries lie on each side; otherwise the side with fewer is dropped).
    Entries that are not finite and positive are dropped; fewer than 3 left (4 with the step) gives
    NaN. A rate whose interval lies above 1 means sustained growth.
    """
    y = np.asarray(series, dtype=np.float64).ravel()
    j = np.arange(y.size, dtype=np.float64) if iterations is None else np.asarray(iterations, dtype=np.float64).ravel()
    if j.shape != y.shape:
        raise ValueError(f"iterations must have one entry per value, got {j.size} for {y.size}")
    if last is not None:
        y, j = y[-last:], j[-last:]
    keep = np.isfinite(y) & (y > 0)
    y, j = np.log(y[keep]), j[keep]
    columns = [np.ones_like(j), j - j.mean()]
    if shift_at is not None:
        after = j >= shift_at
        if min(int(after.sum()), int((~after).sum())) >= 2:
            columns.append(after.astype(np.float64))
        elif after.sum() < (~after).sum():  # too few after the change to place the step: drop them
            y, j, columns = y[~after], j[~after], [np.ones(int((~after).sum())), j[~after] - j[~after].mean()]
        else:
            y, j, columns = y[after], j[after], [np.ones(int(after.sum())), j[after] - j[after].mean()]
    n, p = y.size, len(columns)
    if n < p + 1:
        return Interval(math.nan, math.nan, math.nan, n)
    x = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    cov = np.linalg.pinv(x.T @ x)
    s_b = math.sqrt(max(float(resid @ resid), 0.0) / (n - p) * float(cov[1, 1]))
    t = _t_quantile(0.5 + level / 2.0, n - p)
    slope = float(coef[1])
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
