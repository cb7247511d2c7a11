"""One method's metrics in one seed as plain arrays, for the lookups the claims make per seed.

Judging the claims over a study reads a handful of numbers per (seed, method) thousands of times;
through pandas (``.at``, a string comparison per call) that was most of a study report's time.
:class:`SeedMetrics` answers the same questions as the DataFrame readers of
:mod:`ilcforce.report.tables` (``value_at``, ``divergence``, ``jbar``, ``complete_iterations``,
``chattering_iteration``) with the same results, from arrays built once. :func:`split_seeds`
builds them for every (seed, method) of a tidy frame with one sort instead of a groupby per seed.
``tests/test_comparison.py`` checks every answer against the DataFrame readers.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ilcforce.report.comparison import MethodMetrics

_KEYS = ("seed", "method", "iteration")


#: One (seed, method)'s metrics as arrays: :class:`ilcforce.report.comparison.MethodMetrics`.
SeedMetrics = MethodMetrics


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
