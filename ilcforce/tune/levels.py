"""Each method's held-out front read off at equal chattering: its error objective at one stated settled
chattering level, the same level for every method.

A tuning ships each method's most accurate point under the cap, so two shipped methods can sit at very
different chattering (one at 0.8 of the cap, another at 0.2) and their errors then compare two things at
once. Here every method is read at the same level instead. A level is a fraction of a cap, and a cap is
one settled H per task axis (N): a point's chattering relative to a cap is max over the axes of H_a / cap_a
(so a level of 0.5 x the cap is H_a <= 0.5 cap_a on every axis, with equality on one).

The front is the method's stable held-out points (no seed diverged or was flagged) that no other of its
stable points beats in both (chattering, error objective) (:func:`ilcforce.tune.front.pareto_indices`):
the front the tuning page draws. Along it, error falls as chattering rises. At a level:

* inside the front's range, the error is read by linear interpolation in (chattering / cap, error
  objective) between the two front points around it (exact at a point): "on the front";
* below the front's least chattering, the method never chatters that little: "not reached", with the
  front's low end and how many times the level its chattering is;
* above the front's most chattering, the method was not seen chattering that much: "front ends below",
  with the front's high end (a point the method reaches with less chattering than the level) and how many
  times its chattering the level is.

An interpolated value is a read-off between two measured points, not a measured point itself.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import pandas as pd

from ilcforce.tune.front import pareto_indices

ON_FRONT = "on the front"
NOT_REACHED = "not reached"
ENDS_BELOW = "front ends below"
NO_POINT = "no stable point"


@dataclass(frozen=True)
class Reading:
    """One front read at one level."""

    status: str  # ON_FRONT, NOT_REACHED, ENDS_BELOW or NO_POINT
    error: float  # the error objective at the level (ON_FRONT), else NaN
    between: tuple[int, int] | None  # ON_FRONT: indices (into the points given) of the front points around it
    nearest: int | None  # NOT_REACHED / ENDS_BELOW: index of the front's end nearest the level
    distance: float  # NOT_REACHED: nearest chattering / level; ENDS_BELOW: level / nearest chattering (>= 1)


def read_off(points: Sequence[tuple[float, float]], level: float) -> Reading:
    """The front of ``points`` (each (chattering / cap, error objective), both minimised) read at
    chattering ``level`` (same unit as the points' first entry, > 0)."""
    if not level > 0 or not math.isfinite(level):
        raise ValueError(f"a chattering level must be a positive number, got {level!r}")
    usable = [i for i, (c, e) in enumerate(points) if math.isfinite(c) and math.isfinite(e)]
    front = [usable[k] for k in pareto_indices([points[i] for i in usable])]  # chattering ascending
    if not front:
        return Reading(NO_POINT, math.nan, None, None, math.nan)
    low, high = points[front[0]][0], points[front[-1]][0]
    if level < low:
        return Reading(NOT_REACHED, math.nan, None, front[0], low / level)
    if level > high:
        return Reading(ENDS_BELOW, math.nan, None, front[-1], level / high)
    for a, b in zip(front, front[1:] + front[-1:]):
        (ca, ea), (cb, eb) = points[a], points[b]
        if ca <= level <= cb:
            share = (level - ca) / (cb - ca) if cb > ca else 0.0  # a one-point front: the point itself
            return Reading(ON_FRONT, ea + share * (eb - ea), (a, b), None, 1.0)
    raise AssertionError("unreachable: the level lies within the front's range")


def relative_to(frame: pd.DataFrame, axes: Sequence[str], cap: Sequence[float]) -> pd.Series:
    """Each row's settled chattering relative to ``cap`` (one H per axis of ``axes``, N): max over the axes
    of ``H_<axis> settled`` / cap."""
    ratios = [frame[f"H_{a} settled"].astype(float) / float(c) for a, c in zip(axes, cap, strict=True)]
    return pd.concat(ratios, axis=1).max(axis=1, skipna=False)


def level_table(pareto: pd.DataFrame, methods: Sequence[str], axes: Sequence[str],
                caps: Sequence[tuple[str, Sequence[float], Sequence[float]]]) -> pd.DataFrame:
    """Every method's front read at every level: one row per (cap, fraction, method), in that order.

    ``pareto`` has one row per held-out point (a tuning's ``pareto.csv``: method, trial, ``H_<axis>
    settled``, ``error objective``, ``stable``); ``caps`` holds (name, one H per axis in N, the fractions
    of it to read at). Columns: cap, fraction, ``level H_<axis>`` (N), method, status, error objective
    (at the level; NaN unless on the front), from trial / to trial (the front points around it), nearest
    trial, its chattering / level, its error objective, distance (x: how far the level is from the
    front's nearest end, as a ratio >= 1; 1 on the front)."""
    rows = []
    for name, cap, fractions in caps:
        relative = relative_to(pareto, axes, cap)
        for fraction in fractions:
            for method in methods:
                mine = pareto[(pareto["method"] == method) & pareto["stable"].astype(bool)]
                points = [(float(relative[i]), float(mine.at[i, "error objective"])) for i in mine.index]
                trials = [int(t) for t in mine["trial"]]
                found = read_off(points, float(fraction))
                near = found.nearest
                rows.append({
                    "cap": name, "fraction": float(fraction),
                    **{f"level H_{a}": float(fraction) * float(c) for a, c in zip(axes, cap, strict=True)},
                    "method": method, "status": found.status, "error objective": found.error,
                    "from trial": trials[found.between[0]] if found.between else math.nan,
                    "to trial": trials[found.between[1]] if found.between else math.nan,
                    "nearest trial": trials[near] if near is not None else math.nan,
                    "nearest chattering / level": points[near][0] / fraction if near is not None else math.nan,
                    "nearest error objective": points[near][1] if near is not None else math.nan,
                    "distance (x)": found.distance})
    frame = pd.DataFrame(rows)
    frame.attrs["units"] = {f"level H_{a}": "N" for a in axes}
    return frame
