"""The geometry of a two-objective search: which trials form the front, its hypervolume, when a search has
stopped improving, and which front points are re-evaluated on held-out seeds.

Both objectives are minimised: (error, chattering) in the units of :mod:`ilcforce.tune.spec`. The
hypervolume is the area the front dominates up to the fixed reference point
:data:`ilcforce.tune.objectives.HV_REFERENCE`, so it only grows as trials are added and is comparable
between the trials of one search.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

Point = tuple[float, float]


def pareto_indices(points: Sequence[Point]) -> list[int]:
    """Indices of the non-dominated points (no other point is as good in both objectives and better in
    one), ordered by the first objective; of equal points, the first."""
    order = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1], i))
    front, best_second = [], math.inf
    for i in order:
        if points[i][1] < best_second:
            front.append(i)
            best_second = points[i][1]
    return front


def hypervolume(points: Sequence[Point], reference: Point) -> float:
    """The area dominated by ``points`` and bounded by ``reference`` (points beyond it add nothing)."""
    inside = [p for p in points if p[0] < reference[0] and p[1] < reference[1]]
    area, ceiling = 0.0, reference[1]
    for i in pareto_indices(inside):  # by the first objective ascending: the second descends
        x, y = inside[i]
        area += (reference[0] - x) * (ceiling - y)
        ceiling = y
    return area


def converged(history: Sequence[Point | None], reference: Point, stop_gain: float) -> tuple[bool, float]:
    """Whether a search with trials ``history`` (each its point, None when infeasible or failed) has stopped
    improving: the front's hypervolume gained less than ``stop_gain`` of itself over the last quarter of
    the trials (at least one). A front still empty (no feasible trial) has nothing to improve: it counts as
    converged with gain 0, and the report says it is empty. Returns (converged, that relative gain)."""
    n = len(history)
    last_quarter = max(1, math.ceil(n / 4))
    now = hypervolume([p for p in history if p is not None], reference)
    before = hypervolume([p for p in history[:n - last_quarter] if p is not None], reference)
    if now == 0.0:
        return True, 0.0
    gain = (now - before) / now
    return gain < stop_gain, gain


def spread(front: Sequence[int], most: int) -> list[int]:
    """At most ``most`` of the front's indices (ordered along it), evenly spaced and always both ends."""
    if len(front) <= most:
        return list(front)
    if most < 2:
        return list(front[:most])
    picks = sorted({round(k * (len(front) - 1) / (most - 1)) for k in range(most)})
    return [front[k] for k in picks]
