"""Tables 2 and 3 and the method comparison, built from metrics DataFrames (never from files).

Every function here takes the per-method metrics frames that :func:`ilcforce.store.read_metrics`
returns (indexed by iteration j, counted from 0; columns ``status``, ``fallback_count``,
``diverged_time``, ``position_error_2norm`` (m), ``force_error_2norm`` (N),
``chattering_task_x``/``_y`` (N), ``chattering_joint_1``/``_2`` (N m), ...) and returns a
DataFrame (:func:`h_form_match`: Markdown bullets). Writing the frames to CSV and Markdown is
:mod:`ilcforce.report.table_write`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from ilcforce.report.comparison import (COMPARISON_COLUMNS, COMPARISON_ITERATIONS, INTEGER_COLUMNS,  # noqa: F401
                                 JBAR_FACTOR, JBAR_LAST, JBAR_WINDOW, MethodMetrics, comparison_columns,
                                 comparison_rows, ordered_methods)
from ilcforce.controllers import PAPER_METHODS
from ilcforce.metrics import convergence_iteration
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED
from ilcforce.report import paper
from ilcforce.report.table_write import is_missing

#: The paper's methods in the paper's order (the registry's ``in_paper`` specs); the report expects them.
METHOD_ORDER = PAPER_METHODS

# JBAR_LAST, JBAR_WINDOW, JBAR_FACTOR (the j̄ of docs/model.md#metrics), COMPARISON_ITERATIONS and
# ordered_methods are ilcforce.report.comparison's, imported above (the comparison needs no pandas).

#: Suffixes of the two further forms of H (without t = 0; settled from 20 ms), see ilcforce.metrics.
H_FORMS = ("_no_t0", "_settled")

#: Units of the columns these tables produce; the Markdown renderer appends them to headers.
COLUMN_UNITS = {
    "position_error_2norm": "m",
    "position_error_2norm_paper": "m",
    "force_error_2norm": "N",
    "force_error_2norm_paper": "N",
    "chattering_task_x": "N",
    "chattering_task_x_paper": "N",
    "chattering_task_y": "N",
    "chattering_task_y_paper": "N",
    "chattering_joint_1": "N m",
    "chattering_joint_2": "N m",
    "diverged_time": "s",
    **{f"chattering_task_{axis}{form}": "N" for axis in ("x", "y") for form in ("_no_t0", "_settled")},
}


# ---------------------------------------------------------------------------------------------
# Reading one method's metrics frame
# ---------------------------------------------------------------------------------------------


def complete_iterations(metrics: pd.DataFrame) -> list[int]:
    """Iterations whose status is ``"complete"``, ascending."""
    mask = metrics["status"].astype(str) == STATUS_COMPLETE
    return sorted(int(j) for j in metrics.index[mask.to_numpy()])


def value_at(metrics: pd.DataFrame, column: str, iteration: int) -> float:
    """``metrics[column]`` at ``iteration`` if that iteration is stored and complete, else NaN."""
    if iteration not in metrics.index or column not in metrics.columns:
        return math.nan
    if str(metrics.at[iteration, "status"]) != STATUS_COMPLETE:
        return math.nan
    return float(metrics.at[iteration, column])


def divergence(metrics: pd.DataFrame) -> tuple[int, float] | None:
    """(iteration, time in s) of the first diverged iteration, or None if no iteration diverged."""
    mask = (metrics["status"].astype(str) == STATUS_DIVERGED).to_numpy()
    if not mask.any():
        return None
    j = int(metrics.index[mask][0])
    time = float(metrics.at[j, "diverged_time"]) if "diverged_time" in metrics.columns else math.nan
    return j, time


#: A method that completes its iterations "fails the task" when, at its last complete iteration after
#: the plant's change, an error 2-norm is more than this many times its converged level before the
#: change (the median of its last TASK_LOSS_WINDOW complete iterations before it). The learning laws'
#: re-learning transient after the change (claim 4 asks it be at least 2x at the change) is over
#: by then on every shipped setting; a tenfold error at the end is a task no longer done.
TASK_LOSS_FACTOR = 10.0
TASK_LOSS_WINDOW = 5
TASK_LOSS_COLUMNS = (("position_error_2norm", "e_P", "m"), ("force_error_2norm", "e_F", "N"))
FAILS_THE_TASK = "fails the task"


def task_loss(metrics: pd.DataFrame, perturbation_iteration: int) -> str | None:
    """``"fails the task: e_P 0.091 m at j = 19, 300x its level before j = 10 (0.0003 m)"`` when the
    method completes iterations after the plant's change with an error 2-norm above
    :data:`TASK_LOSS_FACTOR` times its converged level before it; None otherwise (or when there is
    no complete iteration on either side of the change to compare)."""
    complete = complete_iterations(metrics)
    before = [j for j in complete if j < perturbation_iteration][-TASK_LOSS_WINDOW:]
    after = [j for j in complete if j >= perturbation_iteration]
    if not before or not after:
        return None
    last = after[-1]
    said = []
    for column, name, unit in TASK_LOSS_COLUMNS:
        if column not in metrics.columns:
            continue
        level = float(np.median([value_at(metrics, column, j) for j in before]))
        end = value_at(metrics, column, last)
        if math.isfinite(level) and level > 0 and math.isfinite(end) and end > TASK_LOSS_FACTOR * level:
            said.append(f"{name} {end:.3g} {unit} at j = {last}, {end / level:.3g}x its level before "
                        f"j = {perturbation_iteration} ({level:.3g} {unit})")
    return f"{FAILS_THE_TASK}: " + "; ".join(said) if said else None


def describe_divergence(metrics: pd.DataFrame) -> str:
    """``"none"`` or e.g. ``"iteration 12 at t = 0.534 s"``."""
    found = divergence(metrics)
    if found is None:
        return "none"
    j, time = found
    return f"iteration {j} at t = {time:.4g} s"


def jbar(metrics: pd.DataFrame, column: str) -> int | None:
    """Convergence iteration j̄ of ``metrics[column]`` (docs/model.md#metrics), or None.

    None when any of iterations 0..9 is missing or not complete (the definition needs all ten).
    """
    norms = np.array([value_at(metrics, column, j) for j in range(JBAR_LAST + 1)])
    if not np.all(np.isfinite(norms)):
        return None
    found = convergence_iteration(norms, factor=JBAR_FACTOR, window=JBAR_WINDOW, last=JBAR_LAST)
    return None if found is None else int(found)


def chattering_iteration(metrics: pd.DataFrame, preferred: int = paper.CHATTERING_ITERATION) -> int | None:
    """``preferred`` (j = 19) if that iteration is complete, else the last complete one, else None."""
    done = complete_iterations(metrics)
    if preferred in done:
        return preferred
    return done[-1] if done else None


# ---------------------------------------------------------------------------------------------
# Tables
# ---------------------------------------------------------------------------------------------


def _int_or_na(value: int | None) -> object:
    return pd.NA if value is None else int(value)


def table2(metrics_by_method: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """Table 2: convergence iteration j̄ and the error 2-norm at j̄, ours beside the paper's.

    One row per method (C1 included; the paper gives no C1 value, so its paper columns are NaN).
    Columns: ``method``, ``jbar_position``, ``jbar_position_paper``, ``position_error_2norm`` (m,
    at our j̄), ``position_error_2norm_paper``, and the same four for ``force`` (N). j̄ columns
    are nullable integers (<NA> when j̄ cannot be computed, e.g. a divergence before j = 9).
    """
    rows = []
    for method in ordered_methods(metrics_by_method):
        metrics = metrics_by_method[method]
        published = paper.table2_row(method)
        row: dict[str, object] = {"method": method}
        for quantity in ("position", "force"):
            column = f"{quantity}_error_2norm"
            ours = jbar(metrics, column)
            row[f"jbar_{quantity}"] = _int_or_na(ours)
            row[f"jbar_{quantity}_paper"] = _int_or_na(
                None if published is None else getattr(published, f"jbar_{quantity}")
            )
            row[column] = math.nan if ours is None else value_at(metrics, column, ours)
            row[f"{column}_paper"] = math.nan if published is None else getattr(published, column)
        rows.append(row)
    columns = ["method"] + [
        name
        for quantity in ("position", "force")
        for name in (
            f"jbar_{quantity}",
            f"jbar_{quantity}_paper",
            f"{quantity}_error_2norm",
            f"{quantity}_error_2norm_paper",
        )
    ]
    frame = pd.DataFrame(rows, columns=columns)
    for quantity in ("position", "force"):
        for name in (f"jbar_{quantity}", f"jbar_{quantity}_paper"):
            frame[name] = frame[name].astype("Int64")
    frame.attrs["units"] = {c: COLUMN_UNITS[c] for c in columns if c in COLUMN_UNITS}
    return frame


def table3(
    metrics_by_method: Mapping[str, pd.DataFrame], *, iteration: int = paper.CHATTERING_ITERATION
) -> pd.DataFrame:
    """Table 3: chattering H = std(tau_d - tau) at ``iteration`` (j = 19, the paper's "j = 20").

    One row per method present (C1 and C3 carry the paper's values; C2, if present, NaN).
    ``iteration`` is the one actually read: j = 19 if complete, else that method's last complete
    iteration (the caller reports the substitution). Columns: ``method``, ``iteration``,
    ``chattering_task_x``, ``chattering_task_x_paper``, ``chattering_task_y``,
    ``chattering_task_y_paper`` (N), ``chattering_joint_1``, ``chattering_joint_2`` (N m), then
    the two other forms of H in task space, ``chattering_task_<axis>_no_t0`` and ``_settled``
    (NaN when the store predates them).
    """
    rows = []
    for method in ordered_methods(metrics_by_method):
        metrics = metrics_by_method[method]
        published = paper.table3_row(method)
        j = chattering_iteration(metrics, iteration)
        row: dict[str, object] = {"method": method, "iteration": _int_or_na(j)}
        for axis in ("x", "y"):
            column = f"chattering_task_{axis}"
            row[column] = math.nan if j is None else value_at(metrics, column, j)
            row[f"{column}_paper"] = math.nan if published is None else getattr(published, f"task_{axis}")
            for form in H_FORMS:
                row[f"{column}{form}"] = math.nan if j is None else value_at(metrics, f"{column}{form}", j)
        for axis in ("1", "2"):
            column = f"chattering_joint_{axis}"
            row[column] = math.nan if j is None else value_at(metrics, column, j)
        rows.append(row)
    columns = [
        "method",
        "iteration",
        "chattering_task_x",
        "chattering_task_x_paper",
        "chattering_task_y",
        "chattering_task_y_paper",
        "chattering_joint_1",
        "chattering_joint_2",
    ] + [f"chattering_task_{axis}{form}" for axis in ("x", "y") for form in H_FORMS]
    frame = pd.DataFrame(rows, columns=columns)
    frame["iteration"] = frame["iteration"].astype("Int64")
    frame.attrs["units"] = {c: COLUMN_UNITS[c] for c in columns if c in COLUMN_UNITS}
    return frame


def comparison_frame(metrics_by_method: Mapping[str, pd.DataFrame]) -> pd.DataFrame:
    """One row per method: the numbers a reader compares the methods by
    (:func:`ilcforce.report.comparison.comparison_rows`, whose docstring lists the columns), as a frame.
    Integer columns (j̄, the chattering and diverged iterations) are nullable (<NA> where unknown);
    ``attrs["units"]`` names the unit of each column that has one.
    """
    rows = comparison_rows({m: MethodMetrics.from_frame(f) for m, f in metrics_by_method.items()})
    columns = comparison_columns(3 if rows and "chattering_task_u" in rows[0] else 2)  # H per task axis
    frame = pd.DataFrame(rows, columns=list(columns))
    for name in INTEGER_COLUMNS:
        frame[name] = frame[name].astype("Int64")
    frame.attrs["units"] = {name: unit for name, unit in columns.items() if unit}
    return frame


def by_quantity(frame: pd.DataFrame) -> pd.DataFrame:
    """A one-row-per-method frame turned for reading: one row per quantity, one column per method.

    The quantity names carry their unit (``[m]``) from ``frame.attrs["units"]``; the cells keep
    their values (mixed types, object columns), so the Markdown renderer formats each.
    """
    if "method" not in frame.columns or frame.empty:
        return frame
    units = frame.attrs.get("units", {})
    rows = []
    for name in frame.columns:
        if name == "method":
            continue
        row: dict[str, object] = {"quantity": f"{name} [{units[name]}]" if name in units else name}
        for method, value in zip(frame["method"], frame[name], strict=True):
            row[str(method)] = value
        rows.append(row)
    turned = pd.DataFrame(rows, columns=["quantity", *map(str, frame["method"])], dtype=object)
    return turned


#: The three forms of H in task space: column suffix -> how the report names it.
H_FORM_NAMES = {"": "whole grid", "_no_t0": "without t = 0", "_settled": "settled (t >= 20 ms)"}


def h_form_match(table3_frame: pd.DataFrame) -> list[str]:
    """Which form of H comes closest to the paper's Table 3, per method and task axis.

    ``table3_frame`` is :func:`table3`'s frame. For every row with a paper value on an axis, one
    Markdown bullet gives ours / paper for each form and names the form closest in ratio
    (|log(ours / paper)| smallest), or says that no form is within 2x of the paper.
    """
    lines = []
    for row in table3_frame.itertuples(index=False):
        row = row._asdict()
        for axis in ("x", "y"):
            published = row.get(f"chattering_task_{axis}_paper")
            if published is None or is_missing(published) or not published > 0:
                continue
            ratios = {}
            for suffix, name in H_FORM_NAMES.items():
                ours = row.get(f"chattering_task_{axis}{suffix}")
                if ours is not None and not is_missing(ours) and ours > 0:
                    ratios[name] = float(ours) / float(published)
            if not ratios:
                continue
            best = min(ratios, key=lambda n: abs(math.log(ratios[n])))
            shown = ", ".join(f"{name} {ratio:.3g}x" for name, ratio in ratios.items())
            if abs(math.log(ratios[best])) > math.log(2.0):
                verdict = "no form within 2x: the definition does not explain the difference"
            elif max(ratios.values()) <= 1.05 * min(ratios.values()):
                verdict = "the forms agree within 5% (the start transient does not matter here)"
            else:
                verdict = f"closest: {best}"
            lines.append(f"* {row['method']}, {axis.upper()}: ours / paper ({float(published):.3g} N): "
                         f"{shown}; {verdict}.")
    return lines
