"""Per-iteration metrics (docs/model.md#metrics): error norms, chattering, convergence iteration.

Pure numpy; consumes :class:`ilcforce.records.IterationRecord` and never touches files.

Every metric is computed on the **log grid** (``n_log`` samples, 2001 at 1 ms for the paper's
setup) from ``record.log``:

* error norms, for ``e`` = ``position_error`` (m) and ``force_error`` (N), shape (n_log, n) for a
  task of n axes (n = 2 or 3, :func:`ilcforce.records.task_axes`). ``e`` is zero on every axis
  that the selection matrix does not select, so summing over all n columns is the same as taking
  the selected axes only; each norm is one column whatever n:

  - ``*_2norm``: the paper's "2-norm" ``sqrt(sum_k sum_i e_i(t_k)^2)``. It grows with the number
    of samples; of these norms it is the one on the scale of the paper's Table 2.
  - ``*_l2``: the grid-independent L2 norm ``sqrt(dt * sum_k sum_i e_i(t_k)^2)``, ``dt`` the
    log spacing (s); units m s^1/2 or N s^1/2 (tabulated as the signal's unit).
  - ``*_rms``: ``sqrt(mean_k sum_i e_i(t_k)^2)``.
  - ``*_max``: ``max_k ||e(t_k)||`` (Euclidean norm per sample).

* chattering ``H`` (Table 3): the population standard deviation (ddof = 0) over the log grid of
  ``Delta = desired - applied`` input, in task space per axis (``desired_task_input -
  task_input``, N) and in joint space per joint (``desired_torque - torque``, N m), in three
  forms, each its own column (:func:`metric_columns` of n: per axis x, y or u, v, n and per joint):

  - ``chattering_<axis>``: over the whole grid (docs/model.md#metrics, the paper's reading);
  - ``chattering_<axis>_no_t0``: without the t = 0 sample. Every iteration starts at rest while
    the reference asks for dF_yd/dt(0) = 5 pi + 5 N/s, so ``Delta(0)`` is a start mismatch that no
    learning can remove; this form shows how much of H that one sample is;
  - ``chattering_<axis>_settled``: over ``t >= settled_from`` only (default
    :data:`SETTLED_FROM` = 20 ms), after the start transient.

* learned-memory norms (:func:`memory_norms`, not a store column: each method has its own
  memory): the RMS over the control grid of each memory block's per-sample Euclidean norm, and
  the same settled (from :data:`SETTLED_FROM`) and at t = 0 alone.

A **diverged** iteration (status ``"diverged"``; its logs are NaN after the divergence time)
gets NaN for every norm and every ``H``: a norm over a truncated trajectory is not comparable
with one over the full trajectory. It keeps ``status``, ``diverged_time`` and
``fallback_count``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

from ilcforce.records import STATUS_DIVERGED, TASK_DIMENSIONS, IterationRecord, joint_axes, record_dimension, task_axes

_BASE_COLUMNS: dict[str, tuple[str, str]] = {
    "iteration": ("1", "iteration index j, counted from 0"),
    "status": ("", "'complete' or 'diverged'"),
    "fallback_count": ("1", "control samples where the implicit acceleration scheme reused the previous acceleration"),
    "diverged_time": ("s", "time at which the watchdog stopped the iteration; NaN if complete"),
    "position_error_2norm": ("m", "paper's 2-norm sqrt(sum_k |e_P(t_k)|^2) over the log grid"),
    "position_error_l2": ("m s^1/2", "L2 norm sqrt(dt sum_k |e_P(t_k)|^2) over the log grid (unit m s^1/2)"),
    "position_error_rms": ("m", "RMS sqrt(mean_k |e_P(t_k)|^2) over the log grid"),
    "position_error_max": ("m", "max_k |e_P(t_k)| (Euclidean norm per sample)"),
    "force_error_2norm": ("N", "paper's 2-norm sqrt(sum_k |e_F(t_k)|^2) over the log grid"),
    "force_error_l2": ("N s^1/2", "L2 norm sqrt(dt sum_k |e_F(t_k)|^2) over the log grid (unit N s^1/2)"),
    "force_error_rms": ("N", "RMS sqrt(mean_k |e_F(t_k)|^2) over the log grid"),
    "force_error_max": ("N", "max_k |e_F(t_k)| (Euclidean norm per sample)"),
}


def _chattering_columns(n: int) -> list[tuple[str, str, str]]:
    """(column, unit, description) of the whole-grid H of every task axis, then every joint, of n axes."""
    task = [(f"chattering_task_{axis}", "N",
             f"H: population std over the log grid of desired_task_input - task_input, {axis} axis")
            for axis in task_axes(n)]
    joint = [(f"chattering_joint_{axis}", "N m",
              f"H: population std over the log grid of desired_torque - torque, joint {axis}")
             for axis in joint_axes(n)]
    return task + joint


def metric_columns(n: int) -> dict[str, tuple[str, str]]:
    """The metric columns of a task of ``n`` axes (n = 2 or 3), in table order: name -> (unit,
    description); for 2 exactly :data:`METRIC_COLUMNS`.

    The iteration, status, divergence and the error norms (sums over every axis, so one column each
    whatever n), then H whole-grid per task axis (:func:`ilcforce.records.task_axes`: x, y or u, v, n)
    and per joint, then each of those in its ``_no_t0`` and ``_settled`` forms. A fresh dict per call.
    """
    columns = dict(_BASE_COLUMNS)
    chattering = _chattering_columns(n)
    for name, unit, description in chattering:
        columns[name] = (unit, description)
    # The two further forms of H, same units, appended after the whole-grid ones (older 2-axis stores
    # lack them; the store's /metrics is a cache recomputed from the logs).
    for name, unit, description in chattering:
        what = description.removeprefix("H: population std over the log grid of ")
        columns[f"{name}_no_t0"] = (unit, f"H without the t = 0 sample: std over t_k > 0 of {what}")
        columns[f"{name}_settled"] = (unit, f"H settled: std over t_k >= 20 ms (SETTLED_FROM) of {what}")
    return columns


#: Metric columns of a task of 2 axes (every store and study until the 3-axis arm), in table order:
#: name -> (unit, description). Units as everywhere in ilcforce: ``"1"`` for a dimensionless number
#: (an index, a count), ``""`` for text. A 2-axis store keeps one row per iteration with exactly these
#: columns; :func:`metric_columns` gives them for n axes.
METRIC_COLUMNS: dict[str, tuple[str, str]] = metric_columns(2)

#: Every metric column of every task dimension, in table order (those of 2 axes first, then those
#: only a 3-axis task has): for tables that hold rows of either (a study's tidy frame, its units).
KNOWN_METRIC_COLUMNS: dict[str, tuple[str, str]] = {
    name: info for n in TASK_DIMENSIONS for name, info in metric_columns(n).items()}


def metric_order(columns: Iterable[str]) -> list[str]:
    """The metric columns among ``columns``, in table order: :func:`metric_columns` of the first task
    dimension whose first task axis has its H column there (2 before 3: a 2-axis table keeps
    :data:`METRIC_COLUMNS`' order), then every other known metric column there (a table holding rows
    of both dimensions)."""
    present = set(columns)
    first = next((n for n in TASK_DIMENSIONS if f"chattering_task_{task_axes(n)[0]}" in present), TASK_DIMENSIONS[0])
    primary = metric_columns(first)
    return [c for c in [*primary, *(c for c in KNOWN_METRIC_COLUMNS if c not in primary)] if c in present]


def columns_dimension(columns: Iterable[str]) -> int:
    """The task dimension whose :func:`metric_columns` are exactly ``columns`` (as a set);
    ValueError (one line) naming the difference from the nearest when none is."""
    keys = set(columns)
    for n in TASK_DIMENSIONS:
        if keys == set(metric_columns(n)):
            return n
    n = 3 if any(k.startswith("chattering_task_") and k.removeprefix("chattering_task_")[:1] in ("u", "v", "n")
                 for k in keys) else 2
    expected = set(metric_columns(n))
    raise ValueError(f"lacks {sorted(expected - keys)[:3]} or has unknown columns {sorted(keys - expected)[:3]} "
                     f"(the metric columns of a task of {n} axes)")


#: Start of the "settled" window of H and of the learned memories (s): after the start transient of
#: every iteration. The one constant for every settled form (H, memory norms, the claims, the
#: stability test). Why 20 ms: the start mismatch (the robot at rest, the reference asking for
#: dF_d/dt(0) = 20.7 N/s) is gone from sigma within a few ms; 20 ms is 1% of the 2 s trial.
SETTLED_FROM = 0.02

#: Version of the metric definitions. The store's ``/metrics`` is a cache of
#: :func:`iteration_metrics` tagged with this version: a store whose cache has another version, or
#: lacks a column of its :func:`metric_columns`, has its table recomputed from the stored logs on read.
#: Bump it when the definition of an existing column changes; adding a column needs no bump.
METRICS_VERSION = 1

#: Column kinds other than float: "int" or "str".
METRIC_KINDS: dict[str, str] = {"iteration": "int", "status": "str", "fallback_count": "int"}


def column_kind(column: str) -> str:
    """``"int"``, ``"str"`` or ``"float"``: the type of a metric column's values."""
    return METRIC_KINDS.get(column, "float")


_NORM_KINDS = ("2norm", "l2", "rms", "max")


def _log_array(record: IterationRecord, name: str, shape: tuple[int, ...]) -> np.ndarray:
    """``record.log[name]`` as float64, checked to have ``shape``; ValueError names the signal."""
    if name not in record.log:
        raise ValueError(f"record.log is missing signal {name!r} (iteration {record.iteration})")
    array = np.asarray(record.log[name], dtype=np.float64)
    if array.shape != shape:
        raise ValueError(
            f"record.log[{name!r}] has shape {array.shape}, expected {shape} (iteration {record.iteration})"
        )
    return array


def error_norms(error: np.ndarray, dt: float) -> dict[str, float]:
    """The four norms of an error trajectory.

    Parameters
    ----------
    error : ndarray, shape (n_samples, n_axes)
        Error samples on a uniform grid, time-major (any unit U); the norms sum over every axis.
    dt : float
        Grid spacing (s), > 0.

    Returns
    -------
    dict
        ``{"2norm", "l2", "rms", "max"}`` -> float, all in U (``l2`` in U s^1/2).
    """
    squared_norm = np.sum(np.square(error), axis=1)  # |e(t_k)|^2, shape (n,)
    total = float(np.sum(squared_norm))
    return {
        "2norm": float(np.sqrt(total)),
        "l2": float(np.sqrt(dt * total)),
        "rms": float(np.sqrt(np.mean(squared_norm))),
        "max": float(np.sqrt(np.max(squared_norm))),
    }


def iteration_metrics(record: IterationRecord, *, settled_from: float = SETTLED_FROM) -> dict[str, object]:
    """One metrics row for one iteration, keys and order exactly :func:`metric_columns` of the
    record's n (:data:`METRIC_COLUMNS` for 2 axes).

    Parameters
    ----------
    record : IterationRecord
        Its ``log`` must hold ``time`` (n_log,) and ``position_error``, ``force_error``,
        ``task_input``, ``desired_task_input``, ``torque``, ``desired_torque`` (n_log, n), with
        n_log >= 2 on a uniform grid; n (2 or 3) is the width of ``position_error`` and every other
        of these arrays must have it too.
    settled_from : float
        Start (s, >= 0, measured from the first log sample) of the window of the ``_settled``
        form of H; a window with fewer than 2 samples gives NaN.

    Returns
    -------
    dict
        ``iteration`` (int), ``status`` (str), ``fallback_count`` (int), ``diverged_time``
        (float, s) and the float norms / chattering values (NaN for a diverged iteration).
    """
    if "time" not in record.log:
        raise ValueError(f"record.log is missing signal 'time' (iteration {record.iteration})")
    time = np.asarray(record.log["time"], dtype=np.float64)
    if time.ndim != 1 or time.shape[0] < 2:
        raise ValueError(
            f"record.log['time'] must have shape (n_log,) with n_log >= 2, got {time.shape} "
            f"(iteration {record.iteration})"
        )
    n_log = time.shape[0]
    row: dict[str, object] = {
        "iteration": int(record.iteration),
        "status": str(record.status),
        "fallback_count": int(record.fallback_count),
        "diverged_time": float(record.diverged_time),
    }
    try:
        n = record_dimension(record.log)
    except ValueError as error:
        raise ValueError(f"{error} (iteration {record.iteration})") from None
    columns = metric_columns(n)
    signals = {
        name: _log_array(record, name, (n_log, n))
        for name in ("position_error", "force_error", "task_input", "desired_task_input", "torque", "desired_torque")
    }
    if record.status == STATUS_DIVERGED:
        for column in columns:
            row.setdefault(column, float("nan"))
        return row

    # Uniform log grid: the spacing from the end points is exact for t_k = t_0 + k dt.
    dt = float(time[-1] - time[0]) / (n_log - 1)
    for error_name in ("position_error", "force_error"):
        norms = error_norms(signals[error_name], dt)
        for kind in _NORM_KINDS:
            row[f"{error_name}_{kind}"] = norms[kind]
    # Table 3: H = std over the log grid of Delta = tau_d - tau (ddof = 0), task and joint space.
    task_delta = signals["desired_task_input"] - signals["task_input"]
    joint_delta = signals["desired_torque"] - signals["torque"]
    if not (math.isfinite(settled_from) and settled_from >= 0):
        raise ValueError(f"settled_from must be a finite time >= 0 s, got {settled_from!r}")
    settled = (time - time[0]) >= settled_from - 1e-9 * dt  # grid times carry rounding; dt-relative slack
    for name, delta, axes in (("task", task_delta, task_axes(n)), ("joint", joint_delta, joint_axes(n))):
        for column, axis in enumerate(axes):
            row[f"chattering_{name}_{axis}"] = float(np.std(delta[:, column]))
            row[f"chattering_{name}_{axis}_no_t0"] = float(np.std(delta[1:, column]))
            row[f"chattering_{name}_{axis}_settled"] = (
                float(np.std(delta[settled, column])) if np.count_nonzero(settled) >= 2 else float("nan"))
    return {name: row[name] for name in columns}


def settled_sample(sample_time: float, settled_from: float = SETTLED_FROM) -> int:
    """The first control sample of the settled window: k0 = ceil(settled_from / Ts) (200 at 0.1 ms)."""
    if not (math.isfinite(sample_time) and sample_time > 0):
        raise ValueError(f"sample_time must be a finite time > 0 s, got {sample_time!r}")
    return int(math.ceil(settled_from / sample_time - 1e-9))


def memory_norms(memory: Mapping[str, np.ndarray], *, settled_from_sample: int | None = None) -> dict[str, float]:
    """The norm of each learned-memory block, for growth tests over iterations.

    Parameters
    ----------
    memory : mapping name -> ndarray, shape (n_control,) or (n_control, width)
        A controller's ``learned_state()`` (or a record's ``memory``), control grid first.
    settled_from_sample : int or None
        With a sample index k0 (:func:`settled_sample`), two more norms per block: settled (over
        k >= k0) and at the start (k = 0 alone). Why: every iteration starts at rest while the
        reference asks for dF_d/dt(0) = 5 pi + 5 N/s, so sigma(0) is the same start mismatch in
        every iteration and a law that learns from sigma adds it again each time: the memory at
        t = 0 grows linearly while the rest of it stays flat. The whole-grid RMS mixes the two.

    Returns
    -------
    dict
        ``memory_norm_<name>`` -> ``sqrt(mean_k |m(t_k)|^2)``, the RMS over the control grid of
        the per-sample Euclidean norm, in the block's unit (mixed for Theta_hat: it is a size,
        for growth rates); with ``settled_from_sample``, also ``memory_settled_<name>`` (the same
        RMS over k >= k0; NaN if no sample is left) and ``memory_start_<name>`` (``|m(t_0)|``).
        NaN when the block holds a non-finite value (a diverged iteration).
    """
    out = {}
    for name, block in memory.items():
        values = np.asarray(block, dtype=np.float64)
        values = values.reshape(values.shape[0], -1) if values.ndim else values.reshape(1, 1)
        finite = values.size > 0 and bool(np.all(np.isfinite(values)))
        squared = np.sum(np.square(values), axis=1) if finite else None
        out[f"memory_norm_{name}"] = float(np.sqrt(np.mean(squared))) if finite else float("nan")
        if settled_from_sample is None:
            continue
        k0 = int(settled_from_sample)
        if k0 < 0:
            raise ValueError(f"settled_from_sample must be >= 0, got {settled_from_sample!r}")
        out[f"memory_settled_{name}"] = (float(np.sqrt(np.mean(squared[k0:])))
                                         if finite and k0 < squared.shape[0] else float("nan"))
        out[f"memory_start_{name}"] = float(np.sqrt(squared[0])) if finite else float("nan")
    return out


def convergence_iteration(
    norms: Sequence[float] | np.ndarray,
    *,
    factor: float = 1.5,
    window: tuple[int, int] = (5, 9),
    last: int = 9,
) -> int | None:
    """The convergence iteration j-bar (docs/model.md#metrics; the paper never defines it).

    j-bar is the first ``j <= last`` with ``norms[j] <= factor * median(norms[window[0] ..
    window[1]])`` (both window ends inclusive).

    Parameters
    ----------
    norms : array_like, shape (n_iterations,)
        One error norm per iteration, indexed by iteration from 0 (NaN where not available).
    factor : float
        Tolerance factor, >= 1 (1.5 in the report).
    window : (int, int)
        First and last iteration (inclusive) of the settled window, ``0 <= window[0] <=
        window[1]``.
    last : int
        Last iteration that may be returned, >= 0.

    Returns
    -------
    int or None
        j-bar; None when ``norms[0 .. window[1]]`` are not all available and finite (fewer
        than ``window[1] + 1`` finite values, e.g. a run that diverged early) or when no
        ``j <= last`` qualifies.
    """
    if not np.isfinite(factor) or factor < 1:
        raise ValueError(f"factor must be a finite number >= 1, got {factor!r}")
    if len(window) != 2 or not all(isinstance(w, (int, np.integer)) for w in window):
        raise ValueError(f"window must be a pair of ints (first, last), got {window!r}")
    if not 0 <= window[0] <= window[1]:
        raise ValueError(f"window must satisfy 0 <= window[0] <= window[1], got {window!r}")
    if not isinstance(last, (int, np.integer)) or last < 0:
        raise ValueError(f"last must be an int >= 0, got {last!r}")
    values = np.asarray(norms, dtype=np.float64)
    if values.ndim != 1:
        raise ValueError(f"norms must be one-dimensional (one norm per iteration), got shape {values.shape}")
    needed = window[1] + 1
    if values.shape[0] < needed or not np.all(np.isfinite(values[:needed])):
        return None
    threshold = factor * float(np.median(values[window[0] : window[1] + 1]))
    for j in range(min(last, values.shape[0] - 1) + 1):
        if values[j] <= threshold:  # NaN compares False, so it never qualifies
            return j
    return None
