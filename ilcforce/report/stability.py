"""Learning stability per method: does anything grow without bound over the iterations?

A method can track well and never diverge within the iterations run while its learned memory, its
chattering H or its error grows from iteration to iteration; such growth ends in divergence later
(see the ``long-run`` experiment). This module states one test and applies it the same way to a
single run (one seed) and to a study (many seeds).

The test
--------
* Quantities watched: H in task space (whole grid, X and Y), the error 2-norms (position, force)
  and every learned memory's norm (``memory_norm_<name>``, :func:`ilcforce.metrics.memory_norms`)
  that the tidy frame holds.
* Window: the complete iterations after the perturbation (j > p), the later half of them but at
  least :data:`MIN_WINDOW` (all of them when fewer); without a perturbation inside the run, the
  later half of all iterations. The jump at the perturbation is never inside the window.
* Per seed and quantity: :func:`ilcforce.stats.growth_rate` over the window (a geometric rate per
  iteration with a 95% t interval). The quantity **grows** in that seed when the whole interval
  lies above 1.
* Over seeds: a quantity grows when it grows in a strict majority of the seeds where the rate
  could be fitted. A method with at least one growing quantity is flagged **"unstable
  learning"**, whether or not it diverged. Linear growth (a memory that integrates noise, or a
  start mismatch learned again every iteration) passes this test over a window of ten
  iterations as well as geometric growth does: both are unbounded.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ilcforce.report.seedframes import split_seeds
from ilcforce.stats import growth_rate, median_interval

#: A quantity grows in a seed when the lower end of its rate's 95% interval exceeds this (1%/iteration).
MIN_RATE = 1.01
#: The fewest iterations a growth rate is fitted over (when the run has them).
MIN_WINDOW = 9
#: Quantities always watched (metric columns); memory norms are added when present.
WATCHED = ("chattering_task_x", "chattering_task_y", "position_error_2norm", "force_error_2norm")
UNSTABLE = "unstable learning"
#: In place of a stability verdict where no growth rate could be fitted (too few complete iterations).
NOT_FITTED = "not evaluable (too few iterations)"
#: Learned-memory norm columns: ``memory_norm_<name>`` (ilcforce.metrics.memory_norms, the one
#: function single-run reports and study cells share).
MEMORY_PREFIXES = ("memory_norm_",)
#: Short names for the quantities, for flags and tables.
SHORT = {"chattering_task_x": "H_x", "chattering_task_y": "H_y", "position_error_2norm": "|e_P|",
         "force_error_2norm": "|e_F|"}


def short_name(column: str) -> str:
    for prefix in MEMORY_PREFIXES:
        if column.startswith(prefix):
            return f"|{column.removeprefix(prefix)}|"
    return SHORT.get(column, column)


def growth_window(iterations: list[int], perturbation_iteration: int) -> list[int]:
    """The iterations (ascending) whose values the growth rate is fitted over (module docstring)."""
    done = sorted(iterations)
    after = [j for j in done if j > perturbation_iteration]
    pool = after if after else done
    size = max(MIN_WINDOW, math.ceil(len(pool) / 2))
    return pool[-size:] if len(pool) > size else pool


def watched_columns(frame: pd.DataFrame) -> list[str]:
    return [c for c in WATCHED if c in frame.columns] + sorted(
        c for c in frame.columns if c.startswith(MEMORY_PREFIXES))


def learning_growth(metrics: pd.DataFrame, *, perturbation_iteration: int) -> pd.DataFrame:
    """Growth rates per method and quantity over the seeds of ONE setting.

    ``metrics``: tidy frame (``seed``, ``method``, ``iteration``, metric columns, and optionally
    ``memory_norm_*`` columns).

    Returns one row per (method, quantity) with a fittable rate: ``method``, ``quantity``,
    ``window`` (e.g. "j = 11..19"), ``rate`` (median over seeds of the per-iteration rate),
    ``rate_low``, ``rate_high`` (95% bootstrap interval of that median), ``growing`` (seeds whose
    rate interval lies above MIN_RATE), ``fitted`` (seeds with a rate), ``grows`` (bool, majority rule).
    """
    rows = []
    columns = watched_columns(metrics)
    by_seed = split_seeds(metrics)  # seed (ascending) -> method -> arrays sorted by iteration
    for method in dict.fromkeys(metrics["method"].astype(str)):  # methods in order of appearance
        # each seed's window is found once and read for every watched column
        windows = []
        for per_seed in by_seed.values():
            if method not in per_seed:
                continue
            seed = per_seed[method]
            window = growth_window(seed.complete_iterations, perturbation_iteration)
            windows.append((window, {c: seed.columns[c][[seed.position[j] for j in window]] for c in columns}))
        for column in columns:
            rates, lows, seen = [], [], set()
            for window, values_by_column in windows:
                values = np.asarray(values_by_column[column], dtype=float) if window else np.array([])
                if values.size < 3 or not np.all(np.isfinite(values)):
                    continue
                fitted = growth_rate(values)
                if not math.isfinite(fitted.estimate):
                    continue
                rates.append(fitted.estimate)
                lows.append(fitted.low)
                seen.add(f"j = {window[0]}..{window[-1]}")
            if not rates:
                continue
            median = median_interval(rates)
            growing = int(sum(low > MIN_RATE for low in lows))
            rows.append({"method": str(method), "quantity": column, "window": ", ".join(sorted(seen)),
                         "rate": median.estimate, "rate_low": median.low, "rate_high": median.high,
                         "growing": growing, "fitted": len(rates), "grows": bool(2 * growing > len(rates))})
    return pd.DataFrame(rows, columns=["method", "quantity", "window", "rate", "rate_low", "rate_high",
                                       "growing", "fitted", "grows"])


def unstable_methods(growth: pd.DataFrame) -> dict[str, str]:
    """Method -> "unstable learning: H_y x1.05/it (5 of 5 seeds), ..." for every flagged method."""
    flags: dict[str, str] = {}
    for method, frame in growth.groupby("method", sort=False):
        growing = frame[frame["grows"]].sort_values("rate", ascending=False)
        if growing.empty:
            continue
        parts = [f"{short_name(r.quantity)} x{r.rate:.3g}/iteration ({r.growing} of {r.fitted} seeds)"
                 for r in growing.itertuples(index=False)]
        flags[str(method)] = f"{UNSTABLE}: " + ", ".join(parts)
    return flags


def label(method: str, flags: dict[str, str], base: str | None = None) -> str:
    """A method's label with " (unstable learning)" appended when it is flagged."""
    text = base if base is not None else method
    return f"{text} ({UNSTABLE})" if method in flags else text
