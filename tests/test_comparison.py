"""The pandas-free comparison (ilcforce/report/comparison.py) against the DataFrame readers of the report.

:class:`~ilcforce.report.comparison.MethodMetrics` answers the lookups the tables and the claims make
(value at an iteration, first divergence, j̄, the iteration Table 3 reads) from arrays; the
DataFrame readers of :mod:`ilcforce.report.tables` are the slow, readable reference. Both are run
over metrics with complete, diverged and missing iterations, and NaN values, and must agree
exactly; ``comparison_rows`` must equal the comparison assembled from the reference readers.
``ilcforce compare`` prints its table from these rows, so it must not import pandas.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import comparison
from ilcforce.report.comparison import COMPARISON_ITERATIONS, MethodMetrics, comparison_rows
from ilcforce.metrics import METRIC_COLUMNS, column_kind
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED
from ilcforce.report import tables


def _rows(n: int, *, diverge_at: int | None = None, skip: tuple[int, ...] = (), nan_at: tuple[int, ...] = (),
          seed: int = 0) -> dict[int, dict[str, object]]:
    """Metrics rows for iterations 0..n-1 (diverged at ``diverge_at``, then none; ``skip`` missing;
    NaN error norms at ``nan_at``), values pseudo-random but shaped like a learning run."""
    rng = np.random.default_rng(seed)
    rows = {}
    for j in range(n):
        if j in skip:
            continue
        if diverge_at is not None and j > diverge_at:
            break
        row: dict[str, object] = {}
        for column in METRIC_COLUMNS:
            kind = column_kind(column)
            row[column] = {"int": int(rng.integers(0, 50)), "str": STATUS_COMPLETE,
                           "float": float(rng.uniform(0.5, 1.5) / (1 + j))}[kind]
        row["iteration"] = j
        row["diverged_time"] = math.nan
        if j in nan_at:
            row["position_error_2norm"] = math.nan
        if j == diverge_at:
            row["status"] = STATUS_DIVERGED
            row["diverged_time"] = 0.75
        rows[j] = row
    return rows


def _frame(rows: dict[int, dict[str, object]]) -> pd.DataFrame:
    """The DataFrame the store's read_metrics would build from these rows."""
    from ilcforce.store.access import metrics_frame

    return metrics_frame(rows)


CASES = {
    "complete": _rows(20),
    "short": _rows(6),
    "diverged at 12": _rows(20, diverge_at=12, seed=1),
    "diverged at 3": _rows(20, diverge_at=3, seed=2),
    "iteration 4 missing": _rows(20, skip=(4,), seed=3),
    "nan at 7": _rows(20, nan_at=(7,), seed=4),
    "empty": {},
}


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


@pytest.mark.parametrize("case", list(CASES))
def test_method_metrics_answers_as_the_dataframe_readers(case):
    rows = CASES[case]
    frame = _frame(rows)
    fast = MethodMetrics.from_rows(rows)
    from_frame = MethodMetrics.from_frame(frame)
    for m in (fast, from_frame):
        assert m.complete_iterations == tables.complete_iterations(frame), case
        assert m.divergence == tables.divergence(frame) or (  # NaN times compare unequal
            m.divergence is not None and tables.divergence(frame) is not None
            and m.divergence[0] == tables.divergence(frame)[0]), case
        assert m.describe_divergence() == tables.describe_divergence(frame), case
        assert m.chattering_iteration() == tables.chattering_iteration(frame), case
        for column in ("position_error_2norm", "force_error_2norm", "chattering_task_x"):
            assert m.jbar(column) == tables.jbar(frame, column), (case, column)
            for j in range(-1, 22):
                assert _same(m.value_at(column, j), tables.value_at(frame, column, j)), (case, column, j)


def _reference_row(method: str, frame: pd.DataFrame) -> dict[str, object]:
    """The comparison row from the DataFrame readers alone (the readable reference)."""
    row: dict[str, object] = {"method": method, "iterations": len(frame.index)}
    for quantity in ("position", "force"):
        column = f"{quantity}_error_2norm"
        converged = tables.jbar(frame, column)
        row[f"jbar_{quantity}"] = converged
        row[f"{column}_j0"] = tables.value_at(frame, column, 0)
        row[f"{column}_jbar"] = math.nan if converged is None else tables.value_at(frame, column, converged)
        for j in COMPARISON_ITERATIONS[1:]:
            row[f"{column}_j{j}"] = tables.value_at(frame, column, j)
    j_h = tables.chattering_iteration(frame)
    row["chattering_iteration"] = j_h
    for axis in ("x", "y"):
        column = f"chattering_task_{axis}"
        row[column] = math.nan if j_h is None else tables.value_at(frame, column, j_h)
    found = tables.divergence(frame)
    row["divergence"] = tables.describe_divergence(frame)
    row["diverged_iteration"] = None if found is None else found[0]
    row["diverged_time"] = math.nan if found is None else found[1]
    row["fallback_total"] = int(np.nansum(frame["fallback_count"].to_numpy(dtype=float))) if len(frame) else 0
    return row


def test_comparison_rows_equal_the_reference_and_the_frame():
    methods = {"c1": CASES["complete"], "c2": CASES["diverged at 12"], "c3": CASES["nan at 7"],
               "pd-ilc": CASES["iteration 4 missing"], "sl-adapt": CASES["empty"]}
    rows = comparison_rows({m: MethodMetrics.from_rows(r) for m, r in methods.items()})
    assert [row["method"] for row in rows] == ["c1", "c2", "c3", "pd-ilc", "sl-adapt"]  # registry order
    frame = tables.comparison_frame({m: _frame(r) for m, r in methods.items()})
    assert list(frame.columns) == list(comparison.COMPARISON_COLUMNS)
    for row in rows:
        reference = _reference_row(row["method"], _frame(methods[row["method"]]))
        assert list(row) == list(comparison.COMPARISON_COLUMNS)
        for name, value in row.items():
            assert _same(value, reference[name]), (row["method"], name, value, reference[name])
            shown = frame.loc[frame["method"] == row["method"], name].iloc[0]
            assert (pd.isna(shown) if value is None else _same(shown, value)), (row["method"], name)
    assert frame.attrs["units"]["position_error_2norm_j19"] == "m"
    assert frame.attrs["units"]["diverged_time"] == "s"
    for name in comparison.INTEGER_COLUMNS:
        assert str(frame[name].dtype) == "Int64"


def test_a_diverged_run_is_described_with_its_time():
    m = MethodMetrics.from_rows(CASES["diverged at 12"])
    assert m.divergence == (12, 0.75)
    assert m.describe_divergence() == "iteration 12 at t = 0.75 s"
    assert m.chattering_iteration() == 11  # j = 19 did not complete: the last complete one
    assert m.value_at("force_error_2norm", 12) != m.value_at("force_error_2norm", 12)  # NaN: not complete
