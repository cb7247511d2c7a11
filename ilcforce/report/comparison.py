"""The numbers a reader compares methods by, from metrics rows, without pandas.

:class:`MethodMetrics` holds one method's metrics (one run, or one seed of a study) as aligned
arrays and answers the lookups the tables and the claims make: the value at an iteration if that
iteration completed, the first divergence, the convergence iteration j̄ (docs/model.md#metrics), the
iteration Table 3 reads. :func:`comparison_rows` is the method comparison (``ilcforce compare``
prints it; :func:`ilcforce.report.tables.comparison_frame` is the same rows as a DataFrame).

No pandas here: ``ilcforce compare`` prints its table from the stores' metrics rows (about 0.2 s
of CPU less than importing pandas beside the workers). ``tests/test_comparison.py``
checks every answer against a plain reading of the same metrics.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from functools import cached_property

import numpy as np

from ilcforce.controllers import REGISTRY
from ilcforce.metrics import METRIC_COLUMNS, convergence_iteration, metric_order
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED, task_axes
from ilcforce.report import paper

#: Last iteration that may be the convergence iteration j̄, and the window whose median defines
#: "converged" (docs/model.md#metrics: first j <= 9 within 1.5x the median of iterations 5..9).
JBAR_LAST = 9
JBAR_WINDOW = (5, 9)
JBAR_FACTOR = 1.5

#: Iterations at which the comparison samples the error 2-norms.
COMPARISON_ITERATIONS = (0, 9, 10, 19)


def ordered_methods(methods: Iterable[str]) -> list[str]:
    """``methods`` in registry order (the paper's c1, c2, c3 first), then unregistered names sorted."""
    names = set(methods)
    known = [m for m in REGISTRY if m in names]
    return known + sorted(names - set(REGISTRY))


class MethodMetrics:
    """One method's metrics: ``iterations`` ascending, ``status`` and the metric columns aligned."""

    def __init__(self, iterations, columns: dict[str, np.ndarray]) -> None:
        self.iterations = [int(j) for j in iterations]
        self.position = {j: k for k, j in enumerate(self.iterations)}
        self.columns = columns
        status = np.asarray([str(s) for s in columns["status"]], dtype=object)
        self.complete = status == STATUS_COMPLETE
        self.diverged = status == STATUS_DIVERGED
        self._jbar: dict[str, int | None] = {}

    @classmethod
    def from_rows(cls, rows: Mapping[int, Mapping[str, object]]) -> MethodMetrics:
        """From metrics rows keyed by iteration (:func:`ilcforce.store.read_metrics_rows`)."""
        order = sorted(rows)
        # the rows' own metric columns (metric_columns of the store's task dimension), in table order
        names = [c for c in metric_order(rows[order[0]]) if c != "iteration"] if order else \
            [c for c in METRIC_COLUMNS if c != "iteration"]
        return cls(order, {c: np.asarray([rows[j][c] for j in order], dtype=object) for c in names})

    @classmethod
    def from_frame(cls, frame) -> MethodMetrics:
        """From a DataFrame indexed by iteration (any order) with a ``status`` column."""
        frame = frame.sort_index()
        return cls(frame.index.to_numpy(), {c: frame[c].to_numpy() for c in frame.columns})

    def value_at(self, column: str, j: int) -> float:
        """The value at ``j`` if that iteration is stored and complete, else NaN."""
        k = self.position.get(j)
        if k is None or column not in self.columns or not self.complete[k]:
            return math.nan
        return float(self.columns[column][k])

    @cached_property
    def divergence(self) -> tuple[int, float] | None:
        """(iteration, time in s) of the first diverged iteration, or None if none diverged."""
        found = np.flatnonzero(self.diverged)
        if found.size == 0:
            return None
        k = int(found[0])
        time = float(self.columns["diverged_time"][k]) if "diverged_time" in self.columns else math.nan
        return self.iterations[k], time

    @cached_property
    def complete_iterations(self) -> list[int]:
        """Iterations whose status is ``"complete"``, ascending."""
        return [j for j, done in zip(self.iterations, self.complete, strict=True) if done]

    def jbar(self, column: str) -> int | None:
        """Convergence iteration j̄ of ``column`` (docs/model.md#metrics), cached per column; None when
        any of iterations 0..9 is missing or not complete (the definition needs all ten)."""
        if column not in self._jbar:
            norms = np.array([self.value_at(column, j) for j in range(JBAR_LAST + 1)])
            found = None
            if np.all(np.isfinite(norms)):
                found = convergence_iteration(norms, factor=JBAR_FACTOR, window=JBAR_WINDOW, last=JBAR_LAST)
            self._jbar[column] = None if found is None else int(found)
        return self._jbar[column]

    def chattering_iteration(self, preferred: int = paper.CHATTERING_ITERATION) -> int | None:
        """``preferred`` (j = 19) if that iteration is complete, else the last complete one, else None."""
        done = self.complete_iterations
        if preferred in done:
            return preferred
        return done[-1] if done else None

    def describe_divergence(self) -> str:
        """``"none"`` or e.g. ``"iteration 12 at t = 0.534 s"``."""
        if self.divergence is None:
            return "none"
        j, time = self.divergence
        return f"iteration {j} at t = {time:.4g} s"

    def fallback_total(self) -> int:
        """Implicit-loop fallbacks summed over the iterations (NaN and non-numbers skipped)."""
        values = self.columns.get("fallback_count")
        if values is None:
            return 0
        numbers = [float(v) for v in values if isinstance(v, (int, float, np.integer, np.floating))]
        return int(np.nansum(numbers)) if numbers else 0


def comparison_columns(n: int = 2) -> dict[str, str]:
    """The comparison's columns in order, each with its unit ("" when it has none), for a task of ``n``
    axes (the chattering H per task axis: x, y; or u, v, n)."""
    columns = {"method": "", "iterations": ""}
    for quantity, unit in (("position", "m"), ("force", "N")):
        columns[f"jbar_{quantity}"] = ""
        for at in ("j0", "jbar", *(f"j{j}" for j in COMPARISON_ITERATIONS[1:])):
            columns[f"{quantity}_error_2norm_{at}"] = unit
    columns["chattering_iteration"] = ""
    columns.update({f"chattering_task_{axis}": "N" for axis in task_axes(n)})
    columns.update({"divergence": "", "diverged_iteration": "", "diverged_time": "s", "fallback_total": ""})
    return columns


#: The comparison's columns of a 2-axis task, in order: name -> unit ("" when it has none).
COMPARISON_COLUMNS = comparison_columns()
#: Integer columns (None where the iteration does not exist: pandas' nullable Int64 in a frame).
INTEGER_COLUMNS = ("jbar_position", "jbar_force", "chattering_iteration", "diverged_iteration")


def comparison_rows(metrics_by_method: Mapping[str, MethodMetrics]) -> list[dict[str, object]]:
    """One row per method (registry order): :data:`COMPARISON_COLUMNS`.

    ``iterations`` (stored), ``jbar_position`` and the position error 2-norm at j = 0, j̄, 9, 10,
    19 (m), the same for ``force`` (N), ``chattering_iteration`` (19 or the last complete) with
    ``chattering_task_x`` / ``_y`` (N) there, ``divergence`` ("none" or "iteration j at t = ... s"),
    ``diverged_iteration``, ``diverged_time`` (s, NaN if none), ``fallback_total``. A value is NaN
    (None for an integer) where its iteration is missing or did not complete.
    """
    rows = []
    for method in ordered_methods(metrics_by_method):
        m = metrics_by_method[method]
        row: dict[str, object] = {"method": method, "iterations": len(m.iterations)}
        for quantity in ("position", "force"):
            column = f"{quantity}_error_2norm"
            converged = m.jbar(column)
            row[f"jbar_{quantity}"] = converged
            row[f"{column}_j0"] = m.value_at(column, 0)
            row[f"{column}_jbar"] = math.nan if converged is None else m.value_at(column, converged)
            for j in COMPARISON_ITERATIONS[1:]:
                row[f"{column}_j{j}"] = m.value_at(column, j)
        j_h = m.chattering_iteration()
        row["chattering_iteration"] = j_h
        for axis in task_axes(3 if "chattering_task_u" in m.columns else 2):
            column = f"chattering_task_{axis}"
            row[column] = math.nan if j_h is None else m.value_at(column, j_h)
        row["divergence"] = m.describe_divergence()
        row["diverged_iteration"] = None if m.divergence is None else m.divergence[0]
        row["diverged_time"] = math.nan if m.divergence is None else m.divergence[1]
        row["fallback_total"] = m.fallback_total()
        rows.append(row)
    return rows
