"""Learning stability per method: does anything grow without bound over the iterations?

A method can track well and never diverge within the iterations run while its learned memory, its
chattering H or its error grows from iteration to iteration; such growth ends in divergence later
(see the ``long-run`` experiment and the ``long-run-mc`` study). This module states one test and
applies it the same way to a single run (one seed) and to a study (many seeds).

The test
--------
* Quantities judged: H in task space settled (t >= 20 ms, X and Y), the error 2-norms (position,
  force) and every learned memory's norm settled (``memory_settled_<name>``,
  :func:`ilcforce.metrics.memory_norms`). Why settled: every iteration starts at rest while the
  reference asks for a moving force, so sigma(0) is the same start mismatch in every iteration; a
  law that learns from sigma adds it again each time and its memory at t = 0 grows linearly (and
  with it the whole-grid H) while the rest of the trajectory stays flat. That is drift at one
  sample, not growth over the trajectory.
* Shown beside, never judged: H on the whole grid, each memory's whole-grid norm and its value at
  t = 0 alone (``memory_start_<name>``): the initial sample reported on its own.
* Window: the late iterations of the run. Re-learning after the perturbation is bounded and is
  left out: the window starts RELEARN = 5 iterations after the perturbation (after the run's start
  when it has none) and is the later half of the complete iterations from there on, at least
  MIN_WINDOW = 10 of them. A run with fewer is too short to see a trend: not evaluable (the
  paper's 20 iterations leave 5; the ``long-run`` experiment and the ``long-run-mc`` study run 150).
* Per seed and quantity: :func:`ilcforce.stats.growth_rate` over the window (a geometric rate per
  iteration with a 95% t interval). The quantity **grows** in that seed when the whole interval
  lies above MIN_RATE (1% per iteration) **and** its value at the window's end is above the
  quantity's absolute floor (FLOORS: growth of something too small to matter is not flagged).
* Over seeds: a quantity grows when it grows in a strict majority of the seeds where the rate
  could be fitted. A method with at least one growing judged quantity is flagged **"unstable
  learning"**, whether or not it diverged.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ilcforce.report.seedframes import split_seeds
from ilcforce.stats import growth_rate, median_interval

#: A quantity grows in a seed when the lower end of its rate's 95% interval exceeds this (1%/iteration).
MIN_RATE = 1.01
#: The fewest iterations a growth rate is fitted over: a trend needs a run long enough to show one.
MIN_WINDOW = 10
#: Iterations after the perturbation left to re-learning (bounded by design, never judged).
RELEARN = 5
#: Quantities judged (metric columns); settled memory norms are added when present.
WATCHED = ("chattering_task_x_settled", "chattering_task_y_settled", "position_error_2norm", "force_error_2norm")
#: Shown beside the judged quantities, never judged: the forms the start mismatch drives.
SHOWN = ("chattering_task_x", "chattering_task_y")
#: Absolute floors: a quantity whose value at the window's end is at most this is not flagged,
#: whatever its rate. H: the 0.02 N bound of the non-repetitive disturbance (docs/model.md#noise), the
#: size of the paper's own C3 H_y (0.0219 N); errors: the paper's converged C2 2-norms (Table 2,
#: 7.6e-6 m and 0.096 N). A memory norm has mixed units and no floor (0: its rate alone decides).
FLOORS = {"chattering_task_x_settled": 0.02, "chattering_task_y_settled": 0.02,
          "position_error_2norm": 7.6e-6, "force_error_2norm": 0.096}
UNSTABLE = "unstable learning"
#: In place of a stability verdict where no growth rate could be fitted (too few complete iterations).
NOT_FITTED = f"not evaluable (runs too short: fewer than {MIN_WINDOW} late iterations)"
#: Judged learned-memory norm columns (ilcforce.metrics.memory_norms): settled.
MEMORY_PREFIXES = ("memory_settled_",)
#: Shown learned-memory norm columns: whole grid and at t = 0 alone.
SHOWN_MEMORY_PREFIXES = ("memory_norm_", "memory_start_")
#: Short names for the quantities, for flags and tables.
SHORT = {"chattering_task_x": "H_x", "chattering_task_y": "H_y", "chattering_task_x_settled": "H_x settled",
         "chattering_task_y_settled": "H_y settled", "position_error_2norm": "|e_P|", "force_error_2norm": "|e_F|"}
#: The columns of :func:`learning_growth`'s frame.
GROWTH_COLUMNS = ["method", "quantity", "judged", "window", "rate", "rate_low", "rate_high", "growing", "fitted",
                  "grows", "floor", "value_end"]


def short_name(column: str) -> str:
    for prefix, what in (("memory_settled_", "settled"), ("memory_norm_", "whole grid"), ("memory_start_", "t = 0")):
        if column.startswith(prefix):
            return f"|{column.removeprefix(prefix)}| {what}"
    return SHORT.get(column, column)


def growth_window(iterations: list[int], perturbation_iteration: int) -> list[int]:
    """The iterations (ascending) whose values the growth rate is fitted over (module docstring);
    empty when the run has fewer than MIN_WINDOW late iterations."""
    done = sorted(iterations)
    start = perturbation_iteration + RELEARN if done and done[-1] > perturbation_iteration else RELEARN
    pool = [j for j in done if j >= start]
    if len(pool) < MIN_WINDOW:
        return []
    size = max(MIN_WINDOW, math.ceil(len(pool) / 2))
    return pool[-size:]


def watched_columns(frame: pd.DataFrame) -> list[tuple[str, bool]]:
    """(column, judged) for every quantity the test fits: the judged ones first, then the shown."""
    judged = [c for c in WATCHED if c in frame.columns] + sorted(
        c for c in frame.columns if c.startswith(MEMORY_PREFIXES))
    shown = [c for c in SHOWN if c in frame.columns] + sorted(
        c for c in frame.columns if c.startswith(SHOWN_MEMORY_PREFIXES))
    return [(c, True) for c in judged] + [(c, False) for c in shown]


def learning_growth(metrics: pd.DataFrame, *, perturbation_iteration: int) -> pd.DataFrame:
    """Growth rates per method and quantity over the seeds of ONE setting.

    ``metrics``: tidy frame (``seed``, ``method``, ``iteration``, metric columns, and optionally
    ``memory_settled_*``, ``memory_norm_*``, ``memory_start_*`` columns).

    Returns one row per (method, quantity) with a fittable rate: ``method``, ``quantity``,
    ``judged`` (False: shown only), ``window`` (e.g. "j = 75..149"), ``rate`` (median over seeds of
    the per-iteration rate), ``rate_low``, ``rate_high`` (95% bootstrap interval of that median;
    with one seed, that seed's 95% t interval of the fitted rate),
    ``growing`` (seeds whose rate interval lies above MIN_RATE and whose end value is above the
    floor), ``fitted`` (seeds with a rate), ``grows`` (bool, majority rule; always False for a
    shown quantity), ``floor`` (the absolute floor, 0 for none), ``value_end`` (median over seeds
    of the value at the window's last iteration).
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
            windows.append((window, {c: seed.columns[c][[seed.position[j] for j in window]] for c, _ in columns}))
        for column, judged in columns:
            floor = FLOORS.get(column, 0.0)
            rates, grown, ends, seen, fits = [], [], [], set(), []
            for window, values_by_column in windows:
                values = np.asarray(values_by_column[column], dtype=float) if window else np.array([])
                if values.size < 3 or not np.all(np.isfinite(values)):
                    continue
                fitted = growth_rate(values)
                if not math.isfinite(fitted.estimate):
                    continue
                rates.append(fitted.estimate)
                fits.append(fitted)
                ends.append(float(values[-1]))
                grown.append(bool(fitted.low > MIN_RATE and values[-1] > floor))
                seen.add(f"j = {window[0]}..{window[-1]}")
            if not rates:
                continue
            # over seeds: the median rate with its bootstrap interval; one seed: that fit's own t interval
            median = median_interval(rates) if len(rates) > 1 else fits[0]
            growing = int(sum(grown))
            rows.append({"method": str(method), "quantity": column, "judged": judged,
                         "window": ", ".join(sorted(seen)), "rate": median.estimate, "rate_low": median.low,
                         "rate_high": median.high, "growing": growing, "fitted": len(rates),
                         "grows": bool(judged and 2 * growing > len(rates)), "floor": floor,
                         "value_end": float(np.median(ends))})
    return pd.DataFrame(rows, columns=GROWTH_COLUMNS)


def unstable_methods(growth: pd.DataFrame) -> dict[str, str]:
    """Method -> "unstable learning: H_x settled x1.05/it (5 of 5 seeds), ..." for every flagged method."""
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
