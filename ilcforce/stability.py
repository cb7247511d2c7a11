"""Learning stability per method: does anything a law learns, or any settled output, grow without bound?

A method can track well and never diverge within the iterations run while its learned memory, its
chattering H or its error grows from iteration to iteration; such growth ends in divergence later.
This module states one test and applies it the same way to a single run (one seed) and to a study
(many seeds). How well it predicts what long runs do is measured, not assumed: the growth-validation
study (``make long``; docs/long-run/long-run.md) applies it to the first 20, 40, 100 and 200 iterations of runs
of 300 and more and counts what it misses and what it flags falsely. Out of sample, on three held-out sets
drawn after these rules were frozen (docs/long-run/growth-heldout.md, growth-fresh.md, growth-third.md), it
did not meet its target (no miss, at most 10% false alarms from 200 iterations); the midpoint reading
(MIDPOINT_FROM) was added on the third, and on a fourth set drawn after that (growth-fourth.md) it met it:
0 of 21 unbounded runs missed, 0 of 18 bounded ones flagged.

The test
--------
* Quantities judged: H in task space settled (t >= 20 ms, X and Y) and every learned memory's norm: settled (``memory_settled_<name>``), over the whole grid
  (``memory_norm_<name>``) and at t = 0 alone (``memory_start_<name>``) (:func:`ilcforce.metrics.memory_norms`).
  Why the t = 0 memory too: every iteration starts at rest while the reference asks for a moving
  force, so a law that learns from sigma adds the same start mismatch at t = 0 in every iteration;
  long runs show that this drift ends in divergence (noise-free C3 at j = 99, 30 ms into the
  iteration), so it is growth like any other. Shown beside, never judged: H over the whole grid, and
  the error 2-norms: once learning has converged they sit at the noise floor, where they scatter by a
  factor of 4 from one iteration to the next (C2's position error over j = 5..19 of seed 71), so a
  10-point fit finds "growth" in bounded runs (PD-ILC's, flagged at j = 20 before they were set aside);
  what makes a run diverge shows first in H and in the memories.
* Window: the later iterations of the run. Iterations 0..FIRST - 1 (the first learning transient) and
  the RELEARN = 5 iterations from the perturbation on (bounded re-learning) are left out; the window
  is the later half of the rest, but at least MIN_WINDOW = 10 of them and all of them up to SHORT_RUN
  = 30 (a short run has no late part distinct from the rest). The perturbation moves the level of a
  quantity, not its trend, so the fit carries a step there when the window spans it (a 20-iteration
  run is fitted over j = 3..9 and 15..19, a 40-iteration one over 5..9 and 15..39). Fewer than
  MIN_WINDOW: not evaluable. A run of MIDPOINT_FROM = 100 iterations or more is also read as the test
  would have read it at its midpoint (the same window of its first half: j = 54..99 of a 200-iteration
  run), and a quantity grows in a seed when either reading finds it growing: growth that slows inside
  the later window and resumes after it escapes that window alone (the third held-out set).
* Per seed and quantity: :func:`ilcforce.stats.growth_rate` over the window (a geometric rate per
  iteration with a 95% t interval). A memory the law projects onto a bound (alpha_hat <= alpha_max of
  C3-leak and C3-robust) is shown, not judged: its growth is bounded by construction. The quantity
  **grows** in that seed when the whole interval lies
  above MIN_RATE (1% per iteration: 10x in 230 iterations). No floor silences it but one of round-off
  size (a memory's norm below ROUNDOFF = 1e-6 of its block's settled RMS, :func:`negligible`): a quantity too small
  to matter today reaches any size at a steady geometric rate (noise-free C3's settled H_x, 0.003 N at
  j = 19, grows 3.7% per iteration and the run diverges at j = 99). It is **inconclusive** when the
  rate's estimate is above MIN_RATE but its interval reaches below 1 (too noisy to tell). Growth towards
  a limit is not growth without bound: a quantity whose increments from one iteration to the next shrink
  geometrically (:func:`saturates`: their rate's interval below SATURATION = 0.98) is **saturating**, shown
  and not flagged. A memory filling as it learns, or the part of a Q-filtered memory the learning window
  does not update, rises this way; a steady drift (the t = 0 memory of C2 and C3, +0.24 and +0.77 per
  iteration) and geometric growth do not.
* Over seeds: a quantity grows when it grows in a strict majority of the seeds where the rate
  could be fitted. A method with at least one growing judged quantity is flagged **"unstable
  learning"**, whether or not it diverged; its verdict says how fast ("H_x settled grows x1.04 per
  iteration [1.03, 1.05]; at this rate it reaches 10x in 59 iterations").
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from ilcforce.records import task_axes
from ilcforce.stats import growth_rate, median_interval

#: A quantity grows in a seed when the lower end of its rate's 95% interval exceeds this (1%/iteration).
MIN_RATE = 1.01
#: The fewest iterations a growth rate is fitted over: a trend needs a run long enough to show one.
MIN_WINDOW = 10
#: A short run is fitted over all its usable iterations up to this many (a long one over its later half): a
#: short run has no late part distinct from the rest, and every point narrows the rate's interval.
SHORT_RUN = 30
#: The first iterations, the initial learning transient, never judged (j = 0 starts from no memory).
FIRST = 3
#: Iterations from the perturbation on left to re-learning (bounded by design, never judged).
RELEARN = 5
#: From this many iterations on, a run is read twice: over the later half of its iterations and over the later
#: half of its first half (what the test said at the run's midpoint); a quantity grows in a seed when either
#: reading finds it growing (:func:`readings`). Added after the third held-out set (docs/long-run/growth-third.md):
#: there the robust laws' memory at t = 0 grew tenfold over j = 50-100, slowed inside the window j = 104-199
#: (0.87% per iteration, under MIN_RATE) and grew x3,300 by j = 999. Runs shorter than this (the paper's 20
#: iterations, tuning's 60-iteration checks) are read as before.
MIDPOINT_FROM = 100
#: Quantities judged (metric columns, those a frame has); every learned-memory norm is added when present.
#: Settled H per task axis: x, y of a 2-axis task, u, v, n of a 3-axis one (records.task_axes).
WATCHED = ("chattering_task_x_settled", "chattering_task_y_settled",
           *(f"chattering_task_{axis}_settled" for axis in task_axes(3)))
#: Shown beside the judged quantities, never judged: H over the whole grid (the t = 0 sample included) and
#: the error 2-norms (module docstring: at the noise floor their scatter swamps a short fit).
SHOWN = ("chattering_task_x", "chattering_task_y", *(f"chattering_task_{axis}" for axis in task_axes(3)),
         "position_error_2norm", "force_error_2norm")
UNSTABLE = "unstable learning"
#: In place of a stability verdict where no growth rate could be fitted (too few complete iterations).
NOT_FITTED = f"not evaluable (runs too short: fewer than {MIN_WINDOW} iterations past the learning transient)"
#: Judged learned-memory norm columns (ilcforce.metrics.memory_norms): settled, whole grid, t = 0.
MEMORY_PREFIXES = ("memory_settled_", "memory_norm_", "memory_start_")
#: Short names for the quantities, for flags and tables.
SHORT = {"chattering_task_x": "H_x", "chattering_task_y": "H_y", "chattering_task_x_settled": "H_x settled",
         "chattering_task_y_settled": "H_y settled", "position_error_2norm": "|e_P|", "force_error_2norm": "|e_F|",
         **{f"chattering_task_{a}{form}": f"H_{a}{text}" for a in task_axes(3)
            for form, text in (("", ""), ("_settled", " settled"))}}
#: Growth towards a limit: the increments from one iteration to the next shrink by at least this factor per
#: iteration (the whole 95% interval of their rate below it), so what is left to grow is at most 1 / (1 -
#: 0.98) = 50 of the latest increments. A quantity growing this way is not flagged.
SATURATION = 0.98
#: The fewest consecutive increments, 80% of them positive, the saturation fit needs.
MIN_INCREMENTS = 6
#: A learned memory's norm smaller than this fraction of its physical scale at the window's end is numerical
#: residue, not learning, and is not judged in that seed. The scale is what the law has learned: the same
#: block's settled RMS (``memory_settled_<name>``) at the same iteration. Why a floor here when none silences
#: H: a value a millionth of the memory's own size cannot act on the torque, and such values do grow
#: geometrically in bounded runs (C2-robust at q_cutoff = 1500 Hz: its t = 0 memory, which only the
#: zero-phase Q filter's tail reaches across the learning window, grows x2.15 per iteration from 1e-15 N m
#: and is still 5e-7 of the settled memory at j = 39; bounded over 300 iterations).
ROUNDOFF = 1e-6
#: The columns of :func:`learning_growth`'s frame.
GROWTH_COLUMNS = ["method", "quantity", "judged", "window", "rate", "rate_low", "rate_high", "growing", "fitted",
                  "grows", "saturating", "inconclusive", "value_end", "iterations_to_10x"]


def short_name(column: str) -> str:
    for prefix, what in (("memory_settled_", "settled"), ("memory_norm_", "whole grid"), ("memory_start_", "t = 0")):
        if column.startswith(prefix):
            return f"|{column.removeprefix(prefix)}| {what}"
    return SHORT.get(column, column)


def iterations_to_10x(rate: float) -> float:
    """Iterations a quantity growing at ``rate`` per iteration takes to grow tenfold (inf if it does not grow)."""
    return math.log(10.0) / math.log(rate) if math.isfinite(rate) and rate > 1.0 else math.inf


def growth_window(iterations: list[int], perturbation_iteration: int) -> list[int]:
    """The iterations (ascending) whose values the growth rate is fitted over (module docstring);
    empty when fewer than MIN_WINDOW remain."""
    done = sorted(iterations)
    relearn = range(perturbation_iteration, perturbation_iteration + RELEARN)
    pool = [j for j in done if j >= FIRST and j not in relearn]
    if len(pool) < MIN_WINDOW:
        return []
    size = max(MIN_WINDOW, math.ceil(len(pool) / 2), min(len(pool), SHORT_RUN))
    return pool[-size:]


def readings(iterations: list[int], perturbation_iteration: int, midpoint: bool = True) -> list[list[int]]:
    """The windows a run is read over: :func:`growth_window` of all its iterations and, for a run of at least
    MIDPOINT_FROM iterations, of its first half too (empty windows left out). ``midpoint=False``: the first
    alone, the test as it was frozen before the midpoint reading (for the validation pages)."""
    done = sorted(iterations)
    windows = [growth_window(done, perturbation_iteration)]
    if midpoint and done and done[-1] + 1 >= MIDPOINT_FROM:
        windows.append(growth_window([j for j in done if j < (done[-1] + 1) // 2], perturbation_iteration))
    return [w for w in windows if w]


def watched_columns(frame: pd.DataFrame) -> list[tuple[str, bool]]:
    """(column, judged) for every quantity the test fits: the judged ones first, then the shown."""
    judged = [c for c in WATCHED if c in frame.columns] + sorted(
        c for c in frame.columns if c.startswith(MEMORY_PREFIXES))
    shown = [c for c in SHOWN if c in frame.columns]
    return [(c, True) for c in judged] + [(c, False) for c in shown]


def window_text(window: list[int]) -> str:
    """"j = 5..9, 15..19" for a window with a gap, "j = 20..39" without."""
    runs, start = [], window[0]
    for a, b in zip(window, window[1:] + [None], strict=True):
        if b is None or b != a + 1:
            runs.append(f"{start}..{a}")
            start = b
    return "j = " + ", ".join(runs)


def saturates(values, iterations) -> bool:
    """True when a growing series grows towards a limit: its increments between consecutive iterations
    (none across a gap in ``iterations``), at least MIN_INCREMENTS of them and 80% positive, shrink
    geometrically with their rate's whole 95% interval below SATURATION. A steady (linear) drift has
    increments that do not shrink, geometric growth increments that grow: neither saturates."""
    y, j = np.asarray(values, dtype=float), np.asarray(iterations, dtype=float)
    consecutive = np.diff(j) == 1
    steps, at = np.diff(y)[consecutive], j[1:][consecutive]
    if steps.size < MIN_INCREMENTS or np.mean(steps > 0) < 0.8:
        return False
    fitted = growth_rate(steps[steps > 0], iterations=at[steps > 0])
    return bool(math.isfinite(fitted.high) and fitted.high < SATURATION)


def negligible(column: str, values: np.ndarray, values_by_column: Mapping[str, np.ndarray]) -> bool:
    """True for a learned memory's norm below ROUNDOFF of its block's settled RMS at the window's end."""
    prefix = next((p for p in MEMORY_PREFIXES if column.startswith(p)), None)
    scale = values_by_column.get(f"memory_settled_{column.removeprefix(prefix)}") if prefix else None
    if scale is None or not len(scale) or not math.isfinite(float(scale[-1])):
        return False
    return abs(float(values[-1])) < ROUNDOFF * abs(float(scale[-1]))


def capped(config: Mapping[str, object] | None, method: str) -> dict[str, float]:
    """The memories a method's law projects onto a bound (name -> bound): alpha_hat <= alpha_max of
    C3-leak and C3-robust (a finite ``alpha_max`` in the method's section of the resolved ``config``).
    Their growth is bounded by construction, so the test shows it and does not judge it."""
    section = (config or {}).get(method, {})
    bound = section.get("alpha_max") if isinstance(section, Mapping) else None
    return {"alpha_hat": float(bound)} if isinstance(bound, (int, float)) and math.isfinite(bound) else {}


def _runs(metrics: pd.DataFrame, columns: list[str]) -> dict[str, list[tuple[np.ndarray, dict[str, np.ndarray]]]]:
    """method -> per seed (ascending): (its complete iterations ascending, each column's values at them)."""
    complete = metrics[metrics["status"] == "complete"] if "status" in metrics else metrics
    out: dict[str, list] = {}
    for (_seed, method), frame in complete.sort_values(["seed", "method", "iteration"]).groupby(
            ["seed", "method"], sort=True):
        out.setdefault(str(method), []).append(
            (frame["iteration"].to_numpy(), {c: frame[c].to_numpy(dtype=float) for c in columns}))
    return out


def learning_growth(metrics: pd.DataFrame, *, perturbation_iteration: int,
                    config: Mapping[str, object] | None = None, midpoint: bool = True) -> pd.DataFrame:
    """Growth rates per method and quantity over the seeds of ONE setting.

    ``metrics``: tidy frame (``seed``, ``method``, ``iteration``, metric columns, and optionally
    ``memory_settled_*``, ``memory_norm_*``, ``memory_start_*`` columns). ``config``: the setting's
    resolved configuration as a dict, to find the memories a law caps (:func:`capped`: shown, not judged).
    ``midpoint``: read a long run at its midpoint too (:func:`readings`; False only to show the test as it was).

    Returns one row per (method, quantity) with a fittable rate: ``method``, ``quantity``,
    ``judged`` (False: shown only), ``window`` (e.g. "j = 5..9, 15..19"), ``rate`` (median over seeds
    of the per-iteration rate), ``rate_low``, ``rate_high`` (95% bootstrap interval of that median;
    with one seed, that seed's 95% t interval of the fitted rate), ``growing`` (seeds whose rate
    interval lies above MIN_RATE), ``fitted`` (seeds with a rate), ``grows`` (bool, majority rule;
    always False for a shown quantity), ``inconclusive`` (bool: not growing, but the median rate is
    above MIN_RATE while its interval reaches below 1), ``value_end`` (median over seeds of the value at
    the window's last iteration), ``iterations_to_10x`` (at the median rate; inf when it does not grow).
    """
    rows = []
    columns = watched_columns(metrics)
    runs = _runs(metrics, [c for c, _ in columns])
    p = perturbation_iteration
    for method in dict.fromkeys(metrics["method"].astype(str)):  # methods in order of appearance
        # each seed's windows (readings) are found once and read for every watched column
        seeds = []
        for iterations, values in runs.get(method, []):
            seeds.append([(window, {c: values[c][np.searchsorted(iterations, window)] for c, _ in columns})
                          for window in readings(list(iterations), p, midpoint)])
        caps = capped(config, str(method))
        for column, judged in columns:
            judged = judged and not any(column.startswith(prefix) and column.removeprefix(prefix) in caps
                                        for prefix in MEMORY_PREFIXES)
            rates, grown, ends, seen, fits, saturated = [], [], [], set(), [], []
            for windows in seeds:
                read = [r for r in (_read(column, judged, window, by_column, p) for window, by_column in windows) if r]
                if not read:
                    continue
                # the seed's reading: the fastest one that grows, else the whole run's (the first)
                rising = [r for r in read if r[2]]
                window, fitted, growing, levelling, end = max(rising, key=lambda r: r[1].estimate) if rising else read[0]
                rates.append(fitted.estimate)
                fits.append(fitted)
                ends.append(end)
                grown.append(growing)
                saturated.append(levelling)
                seen.add(window_text(window))
            if not rates:
                continue
            # over seeds: the median rate with its bootstrap interval; one seed: that fit's own t interval
            median = median_interval(rates) if len(rates) > 1 else fits[0]
            growing = int(sum(grown))
            grows = bool(judged and 2 * growing > len(rates))
            rows.append({"method": str(method), "quantity": column, "judged": judged,
                         "window": "; ".join(sorted(seen)), "rate": median.estimate, "rate_low": median.low,
                         "rate_high": median.high, "growing": growing, "fitted": len(rates), "grows": grows,
                         "saturating": bool(not grows and 2 * sum(saturated) > len(rates)),
                         "inconclusive": bool(judged and not grows and median.estimate > MIN_RATE
                                              and median.low < 1.0),
                         "value_end": float(np.median(ends)), "iterations_to_10x": iterations_to_10x(median.estimate)})
    return pd.DataFrame(rows, columns=GROWTH_COLUMNS)


def _read(column: str, judged: bool, window: list[int], values_by_column: Mapping[str, np.ndarray], p: int):
    """One reading of one quantity in one seed: (window, fitted rate, grows, saturating, value at the window's
    end), or None where it cannot be read (too few or non-finite values, a judged memory of round-off size)."""
    values = np.asarray(values_by_column[column], dtype=float)
    if values.size < 3 or not np.all(np.isfinite(values)):
        return None
    if judged and negligible(column, values, values_by_column):
        return None
    fitted = growth_rate(values, iterations=window, shift_at=p)
    if not math.isfinite(fitted.estimate):
        return None
    rising = bool(fitted.low > MIN_RATE)
    levelling = rising and saturates(values, window)
    return window, fitted, rising and not levelling, levelling, float(values[-1])


def growth_text(row) -> str:
    """"H_x settled grows x1.04 per iteration [1.03, 1.05]; at this rate it reaches 10x in 59 iterations"."""
    reach = row.iterations_to_10x
    tail = f"; at this rate it reaches 10x in {reach:.0f} iterations" if math.isfinite(reach) else ""
    return (f"{short_name(row.quantity)} grows x{row.rate:.3g} per iteration [{row.rate_low:.3g}, "
            f"{row.rate_high:.3g}]{tail}")


def unstable_methods(growth: pd.DataFrame) -> dict[str, str]:
    """Method -> "unstable learning: H_x settled grows x1.05 per iteration [...] (5 of 5 seeds), ..." for
    every flagged method, its fastest-growing quantity first."""
    flags: dict[str, str] = {}
    for method, frame in growth.groupby("method", sort=False):
        growing = frame[frame["grows"]].sort_values("rate", ascending=False)
        if growing.empty:
            continue
        parts = [f"{growth_text(r)} ({r.growing} of {r.fitted} seeds)" for r in growing.itertuples(index=False)]
        flags[str(method)] = f"{UNSTABLE}: " + ", ".join(parts)
    return flags


def verdict(growth: pd.DataFrame, method: str) -> str:
    """One method's verdict over the window: "grows" (flagged), "inconclusive" (a judged rate above
    MIN_RATE whose interval reaches below 1, none growing), "no growth" (no judged quantity grows
    over the window: not a proof of boundedness beyond it), or "not evaluable" (no rate could be fitted)."""
    mine = growth[(growth["method"] == method) & growth["judged"]]
    if mine.empty:
        return "not evaluable"
    if mine["grows"].any():
        return "grows"
    if mine["inconclusive"].any():
        return "inconclusive"
    return "no growth"


def label(method: str, flags: dict[str, str], base: str | None = None) -> str:
    """A method's label with " (unstable learning)" appended when it is flagged."""
    text = base if base is not None else method
    return f"{text} ({UNSTABLE})" if method in flags else text


#: The growth test's verdict on one run: flagged (it diverged, or a judged quantity grows), not flagged
#: ("no growth"), or not evaluable (inconclusive, or too few iterations).
FLAGGED, NOT_FLAGGED, NOT_EVALUABLE = "flagged", "not flagged", "not evaluable"


def diverged_at(frame: pd.DataFrame) -> float:
    """The first iteration that did not complete (NaN when every one did)."""
    bad = frame.loc[frame["status"] != "complete", "iteration"]
    return float(bad.min()) if len(bad) else math.nan


def verdict_of(frame: pd.DataFrame, method: str, horizon: int, perturbation_iteration: int,
               config: dict | None = None, midpoint: bool = True) -> tuple[str, str]:
    """(class, text) of the growth test on the first ``horizon`` iterations of one run (``midpoint``: as in
    :func:`learning_growth`)."""
    first = frame[frame["iteration"] < horizon]
    diverged = diverged_at(first)
    if math.isfinite(diverged):
        return FLAGGED, f"diverged at j = {int(diverged)}"
    growth = learning_growth(first, perturbation_iteration=perturbation_iteration, config=config, midpoint=midpoint)
    said = verdict(growth, method)
    if said == "grows":
        fastest = growth[growth["grows"]].sort_values("rate", ascending=False).iloc[0]
        return FLAGGED, growth_text(fastest)
    if said == "no growth":
        return NOT_FLAGGED, "no growth"
    if said == "inconclusive":
        unsure = growth[growth["inconclusive"]].sort_values("rate", ascending=False).iloc[0]
        return NOT_EVALUABLE, (f"inconclusive: {short_name(unsure.quantity)} x{unsure.rate:.3g} "
                               f"[{unsure.rate_low:.3g}, {unsure.rate_high:.3g}]")
    return NOT_EVALUABLE, NOT_FITTED
