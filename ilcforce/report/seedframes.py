"""One method's metrics in one seed as plain arrays, for the lookups the claims make per seed.

Judging the claims over a study reads a handful of numbers per (seed, method) thousands of times;
through pandas (``.at``, a string comparison per call) that was most of a study report's time.
:class:`SeedMetrics` answers the same questions as the DataFrame readers of
:mod:`ilcforce.report.tables` (``value_at``, ``divergence``, ``jbar``, ``complete_iterations``,
``chattering_iteration``) with the same results, from arrays built once. :func:`split_seeds`
builds them for every (seed, method) of a tidy frame with one sort instead of a groupby per seed.
``tests/test_report_seedframes.py`` checks every answer against the DataFrame readers.
"""

from __future__ import annotations

import math
from functools import cached_property

import numpy as np
import pandas as pd

from ilcforce.metrics import convergence_iteration
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED
from ilcforce.report import paper, tables

_KEYS = ("seed", "method", "iteration")


class SeedMetrics:
    """The metrics of one (seed, method): ``iterations`` ascending, ``status`` and metric columns aligned."""

    def __init__(self, iterations: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        self.iterations = [int(j) for j in iterations]
        self.position = {j: k for k, j in enumerate(self.iterations)}
        self.columns = columns
        status = np.asarray([str(s) for s in columns["status"]], dtype=object)
        self.complete = status == STATUS_COMPLETE
        self.diverged = status == STATUS_DIVERGED
        self._jbar: dict[str, int | None] = {}

    @classmethod
    def from_frame(cls, frame: pd.DataFrame) -> SeedMetrics:
        """From a frame indexed by iteration (any order) with a ``status`` column."""
        frame = frame.sort_index()
        return cls(frame.index.to_numpy(), {c: frame[c].to_numpy() for c in frame.columns})

    def value_at(self, column: str, j: int) -> float:
        """:func:`tables.value_at`: the value at ``j`` if stored and complete, else NaN."""
        k = self.position.get(j)
        if k is None or column not in self.columns or not self.complete[k]:
            return math.nan
        return float(self.columns[column][k])

    @cached_property
    def divergence(self) -> tuple[int, float] | None:
        """:func:`tables.divergence`: (iteration, time) of the first diverged iteration, or None."""
        found = np.flatnonzero(self.diverged)
        if found.size == 0:
            return None
        k = int(found[0])
        time = float(self.columns["diverged_time"][k]) if "diverged_time" in self.columns else math.nan
        return self.iterations[k], time

    @cached_property
    def complete_iterations(self) -> list[int]:
        """:func:`tables.complete_iterations`."""
        return [j for j, done in zip(self.iterations, self.complete, strict=True) if done]

    def jbar(self, column: str) -> int | None:
        """:func:`tables.jbar` (SPEC section 6), cached per column."""
        if column not in self._jbar:
            norms = np.array([self.value_at(column, j) for j in range(tables.JBAR_LAST + 1)])
            found = None
            if np.all(np.isfinite(norms)):
                found = convergence_iteration(norms, factor=tables.JBAR_FACTOR, window=tables.JBAR_WINDOW,
                                              last=tables.JBAR_LAST)
            self._jbar[column] = None if found is None else int(found)
        return self._jbar[column]

    def chattering_iteration(self, preferred: int = paper.CHATTERING_ITERATION) -> int | None:
        """:func:`tables.chattering_iteration`."""
        done = self.complete_iterations
        if preferred in done:
            return preferred
        return done[-1] if done else None


def split_seeds(metrics: pd.DataFrame) -> dict[int, dict[str, SeedMetrics]]:
    """seed (ascending) -> method -> :class:`SeedMetrics` of a tidy frame (``seed``, ``method``,
    ``iteration`` + metric columns). Every column but the three keys is kept."""
    if metrics.empty:
        return {}
    seeds = metrics["seed"].to_numpy()
    methods = metrics["method"].astype(str).to_numpy()
    iterations = metrics["iteration"].to_numpy()
    order = np.lexsort((iterations, methods, seeds))
    columns = {c: metrics[c].to_numpy()[order] for c in metrics.columns if c not in _KEYS}
    seeds, methods, iterations = seeds[order], methods[order], iterations[order]
    starts = np.flatnonzero(np.r_[True, (seeds[1:] != seeds[:-1]) | (methods[1:] != methods[:-1])])
    ends = np.r_[starts[1:], len(order)]
    out: dict[int, dict[str, SeedMetrics]] = {}
    for start, end in zip(starts, ends, strict=True):
        part = {c: values[start:end] for c, values in columns.items()}
        out.setdefault(int(seeds[start]), {})[str(methods[start])] = SeedMetrics(iterations[start:end], part)
    return out
