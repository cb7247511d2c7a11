"""The HDF5 results store: one self-describing file per (experiment, method).

The only module that imports h5py. One file per (experiment, method):
``results/<experiment>/<method>.h5``.

Layout (schema ``ilcforce.store`` version ``SCHEMA_VERSION``)::

    /                       attrs: schema, schema_version, ilcforce_version, git_commit, created_utc,
                                   updated_utc, command, experiment, method, seed, config_toml,
                                   config_json, run_state ("running" | "partial" | "complete" |
                                   "diverged"), n_iterations_requested
    /reference/<signal>     records.REFERENCE_SIGNALS, each with attrs units, description, axes
    /iterations/<jjjj>/     attrs: iteration, status, diverged_time, diverged_reason,
                                   fallback_count, complete (True, written last)
        log/<signal>        records.LOG_SIGNALS, attrs units, description, axes
        memory/<name>       learned memory at the control rate, attrs units, description
    /metrics/<column>       one row per stored iteration (metrics.METRIC_COLUMNS), attrs units,
                            description

Details
-------
* Root attributes: ``schema`` is ``"ilcforce.store"``; ``schema_version`` is ``"major.minor"``
  (a reader refuses a file whose major is greater than its own and reads any other);
  ``ilcforce_version`` is ``ilcforce.__version__``; ``git_commit`` is ``git rev-parse HEAD`` of
  the package's checkout ("" when unavailable); ``created_utc`` (when the writer was opened)
  and ``updated_utc`` (last commit) are ISO 8601 UTC strings; ``command`` is the command line;
  ``seed`` is an int; ``config_toml`` / ``config_json`` are the resolved configuration as TOML
  and JSON text; ``n_iterations_requested`` is an int. After a resume, ``command``,
  ``config_toml``, ``config_json`` and ``n_iterations_requested`` describe the latest (resuming)
  invocation; ``created_utc`` keeps the first.
* ``run_state``: ``"running"`` while a writer is committing iterations (also what a killed run
  leaves behind), ``"partial"`` when the writer stopped without :meth:`StoreWriter.finish`
  (exception, Ctrl-C), ``"complete"`` / ``"diverged"`` as passed to ``finish``.
* Iteration groups are named with ``j`` zero-padded to 4 digits (``0000``, ``0001``, ...);
  readers parse the name as an int. Group attrs: ``iteration`` (int), ``status`` (str,
  ``"complete"`` | ``"diverged"``), ``diverged_time`` (float, s, NaN if complete),
  ``diverged_reason`` (str), ``fallback_count`` (int), ``complete`` (bool). A group whose
  ``complete`` attr is missing or False is ignored by every reader.
* ``log/<signal>``: float64, shape (n_log,) or (n_log, 2), time-major, on the log grid whose
  length is that of ``/reference/time``; NaN after a divergence. Uncompressed.
* ``memory/<name>``: float64, shape (n_control, ...), the learned memory *after* iteration j
  (the memory iteration j + 1 starts from), uncompressed; units from
  ``IterationRecord.memory_units``.
* ``axes`` attrs are arrays of strings (the column labels, e.g. ``["x", "y"]`` or
  ``["1", "2"]``); scalar-per-sample signals have no ``axes`` attr.
* ``/metrics/<column>``: resizable 1-D datasets (maxshape None), one row per committed
  iteration in commit order; ``iteration`` and ``fallback_count`` are int64, ``status`` is a
  variable-length UTF-8 string, the rest float64 (NaN for a diverged iteration).

Crash safety: each iteration is committed atomically (the file is copied beside itself to
``<path>.tmp-<pid>``, the iteration appended to the copy, and the copy renamed over the original
with os.replace), so a kill -9 at any moment leaves a file that opens and validates with every
finished iteration (a leftover ``.tmp-<pid>`` / ``.tmp-<pid>.prev`` is removed by the next writer
and ignored by readers). The copy is not fsync'ed: the guarantee covers a killed process, not a
power cut. A second writer on the same path is refused (fcntl.flock on ``<path>.lock``; the lock
file may stay behind).

Speed: copying the whole file for every commit costs O(file size) (median 60 ms at iteration
19 of the paper's setup, a 40 MB file: the copy plus the kernel freeing the replaced file).
So the writer keeps the copy between commits instead of making a new one: before the rename it
hard-links the committed file to ``<path>.tmp-<pid>.prev``, and after the rename it applies the
same change to that old file (no longer reachable under ``path``), which becomes the next
commit's copy. A commit then writes one iteration twice, independent of the file size (median
23 ms at iteration 19). The old file is modified only if HDF5 can take an exclusive lock on it
(``locking=True``), i.e. no reader that opened it before the rename still has it open;
otherwise, or without hard links, or when ``HDF5_USE_FILE_LOCKING`` disables HDF5's locks, the
writer falls back to a fresh ``shutil.copyfile`` at the next commit. The committed file is
never modified in place. Costs: a second copy of the file on disk while the writer runs, and a
reader that opens ``path`` in the microseconds around a rename can meet the writer's lock, so
readers retry the open (three tries, 50 ms apart). A reader that disables HDF5 locking and
keeps a file open across a commit is not protected.

Errors: every problem with a file raises :class:`StoreError` whose message is one line naming
the file and the problem (the CLI prints it and exits with status 2). A malformed
:class:`~ilcforce.records.IterationRecord` or reference (a programming error, not a file
problem) raises ValueError naming the bad argument.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import subprocess
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from time import sleep
from types import TracebackType
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

if TYPE_CHECKING:  # pandas is imported by the readers that build frames: writing a run needs none
    import pandas as pd

import ilcforce
from ilcforce.metrics import METRIC_COLUMNS, iteration_metrics
from ilcforce.records import (
    LOG_SIGNALS,
    REFERENCE_SIGNALS,
    STATUS_COMPLETE,
    STATUS_DIVERGED,
    IterationRecord,
)

SCHEMA_NAME = "ilcforce.store"
SCHEMA_VERSION = "1.0"

RUN_STATES = ("running", "partial", "complete", "diverged")

#: Root attributes every store carries (validated by :func:`validate`).
ROOT_ATTRS = (
    "schema",
    "schema_version",
    "ilcforce_version",
    "git_commit",
    "created_utc",
    "updated_utc",
    "command",
    "experiment",
    "method",
    "seed",
    "config_toml",
    "config_json",
    "run_state",
    "n_iterations_requested",
)

#: Attributes every complete iteration group carries.
ITERATION_ATTRS = ("iteration", "status", "diverged_time", "diverged_reason", "fallback_count", "complete")

_INT_METRICS = ("iteration", "fallback_count")
_STR_METRICS = ("status",)
_METRICS_CHUNK = 64  # rows per chunk of a /metrics column: a few hundred bytes, one chunk per run


class StoreError(Exception):
    """A problem with a store file. The message is one line naming the file and the problem."""

    def __init__(self, message: str) -> None:
        super().__init__(_one_line(message))


class StoreLockedError(StoreError):
    """Another process (or another open writer) is writing the same store."""


class StoreExistsError(StoreError):
    """The store exists and neither overwrite nor resume was asked for."""


# ----------------------------------------------------------------------------------------------
# small helpers


def _one_line(text: object) -> str:
    """``text`` as one line (newlines and runs of blanks collapsed)."""
    return " ".join(str(text).split())


def _utc_now() -> str:
    """Current time as ISO 8601 UTC, e.g. ``2025-01-31T12:00:00+00:00``."""
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def _git_commit() -> str:
    """``git rev-parse HEAD`` of the checkout holding this package; "" if unavailable. Never fails."""
    try:
        result = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.SubprocessError, ValueError):
        return ""
    commit = result.stdout.strip()
    if result.returncode != 0 or not commit or any(c not in "0123456789abcdef" for c in commit):
        return ""
    return commit


def _py(value: Any) -> Any:
    """An HDF5 attribute value as a plain python object (str, int, float, bool, list)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        return [_py(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def _parse_version(text: str) -> tuple[int, int]:
    """``"major.minor"`` -> (major, minor); ValueError if malformed."""
    major, minor = str(text).split(".")
    return int(major), int(minor)


def _column_names(signal: str, axes: tuple[str, ...] | None) -> list[str]:
    """DataFrame column names of a signal: ``<signal>_<axis>`` per axis, or ``<signal>``."""
    return [signal] if axes is None else [f"{signal}_{axis}" for axis in axes]


def _describe(dataset: h5py.Dataset, unit: str, description: str, axes: tuple[str, ...] | None) -> None:
    """Attach the self-description attrs to a dataset."""
    dataset.attrs["units"] = unit
    dataset.attrs["description"] = description
    if axes is not None:
        dataset.attrs["axes"] = list(axes)


def _signal_array(
    arrays: Mapping[str, np.ndarray],
    argument: str,
    name: str,
    axes: tuple[str, ...] | None,
    n_samples: int,
) -> np.ndarray:
    """``arrays[name]`` as float64, shape (n_samples,) or (n_samples, len(axes)); ValueError otherwise."""
    if name not in arrays:
        raise ValueError(f"{argument} is missing signal {name!r}")
    array = np.asarray(arrays[name], dtype=np.float64)
    expected = (n_samples,) if axes is None else (n_samples, len(axes))
    if array.shape != expected:
        raise ValueError(f"{argument}[{name!r}] has shape {array.shape}, expected {expected}")
    return array


# ----------------------------------------------------------------------------------------------
# reading and validation


@dataclass(frozen=True)
class _Layout:
    """What validation learnt about an open store.

    Attributes
    ----------
    n_log : int
        Length of the log grid (``/reference/time``).
    complete : tuple[int, ...]
        Complete iterations, ascending.
    groups : dict[int, str]
        Iteration -> HDF5 path of its group, for the complete iterations.
    """

    n_log: int
    complete: tuple[int, ...]
    groups: dict[int, str]


@contextmanager
def _open_store(path: str | os.PathLike[str]) -> Iterator[tuple[h5py.File, Path]]:
    """Open a store read-only, check its header, and turn every h5py failure into StoreError.

    The file is always closed when the block ends.
    """
    path = Path(path)
    if not path.exists():
        raise StoreError(f"{path}: no such file")
    if not path.is_file():
        raise StoreError(f"{path}: not a regular file")
    try:
        size = path.stat().st_size
    except OSError as error:
        raise StoreError(f"{path}: cannot stat ({error.strerror or error})") from None
    if size == 0:
        raise StoreError(f"{path}: empty file (0 bytes), not a readable HDF5 file")
    attempts = 3
    for attempt in range(attempts):
        try:
            handle = h5py.File(path, "r")
            break
        except (OSError, ValueError, RuntimeError) as error:
            if "unable to lock file" in str(error):
                # A writer may have just renamed a new file over this one and be updating the
                # old one (module docstring, Speed): opening again finds the new file.
                if attempt + 1 < attempts:
                    sleep(0.05)
                    continue
                raise StoreError(f"{path}: locked by another program writing it with HDF5 ({_one_line(error)})") from None
            raise StoreError(f"{path}: not a readable HDF5 file ({_one_line(error)})") from None
    try:
        with handle:
            _check_header(handle, path)
            yield handle, path
    except StoreError:
        raise
    except (OSError, KeyError, ValueError, TypeError, RuntimeError, AttributeError) as error:
        raise StoreError(f"{path}: corrupt or unreadable store ({type(error).__name__}: {_one_line(error)})") from None


def _check_header(handle: h5py.File, path: Path) -> None:
    """Schema name, schema version and the presence of every root attribute."""
    if "schema" not in handle.attrs:
        raise StoreError(f"{path}: not an ilcforce store (HDF5 file without a 'schema' attribute)")
    schema = _py(handle.attrs["schema"])
    if schema != SCHEMA_NAME:
        raise StoreError(f"{path}: not an ilcforce store (schema {schema!r}, expected {SCHEMA_NAME!r})")
    if "schema_version" not in handle.attrs:
        raise StoreError(f"{path}: ilcforce store without a 'schema_version' attribute")
    version = _py(handle.attrs["schema_version"])
    try:
        major, _minor = _parse_version(version)
    except ValueError:
        raise StoreError(f"{path}: unreadable schema_version {version!r} (expected 'major.minor')") from None
    if major > _parse_version(SCHEMA_VERSION)[0]:
        raise StoreError(
            f"{path}: written by a newer ilcforce (schema {version}); upgrade to read it "
            f"(this ilcforce reads schema {SCHEMA_VERSION})"
        )
    missing = [name for name in ROOT_ATTRS if name not in handle.attrs]
    if missing:
        raise StoreError(f"{path}: store is missing root attributes {', '.join(missing)}")
    run_state = _py(handle.attrs["run_state"])
    if run_state not in RUN_STATES:
        raise StoreError(f"{path}: unknown run_state {run_state!r} (expected one of {', '.join(RUN_STATES)})")


def _require_group(handle: h5py.File | h5py.Group, name: str, path: Path) -> h5py.Group:
    item = handle.get(name)
    if not isinstance(item, h5py.Group):
        raise StoreError(f"{path}: missing group /{name.strip('/')}" if item is None else f"{path}: /{name} is not a group")
    return item


def _require_dataset(group: h5py.Group, name: str, shape: tuple[int, ...], path: Path) -> h5py.Dataset:
    item = group.get(name)
    where = f"{group.name.rstrip('/')}/{name}"
    if not isinstance(item, h5py.Dataset):
        raise StoreError(f"{path}: missing dataset {where}")
    if item.shape != shape:
        raise StoreError(f"{path}: dataset {where} has shape {item.shape}, expected {shape}")
    return item


def _check_units(group: h5py.Group, path: Path) -> None:
    """Every dataset below ``group`` has a ``units`` attribute."""
    missing: list[str] = []

    def visit(name: str, item: Any) -> None:
        if isinstance(item, h5py.Dataset) and "units" not in item.attrs:
            missing.append(item.name)

    group.visititems(visit)
    if missing:
        raise StoreError(f"{path}: dataset {missing[0]} has no 'units' attribute ({len(missing)} without units)")


def _is_complete(group: h5py.Group) -> bool:
    flag = group.attrs.get("complete", False)
    try:
        return bool(_py(flag))
    except (TypeError, ValueError):
        return False


def _scan(handle: h5py.File, path: Path) -> _Layout:
    """The layout readers need: log length and the complete iterations (attributes only).

    Readers use this instead of the full :func:`_validate_open`, whose per-dataset checks would make
    every read cost O(file size); :func:`validate` and writers do the full check.
    """
    reference = _require_group(handle, "reference", path)
    time = reference.get("time")
    if not isinstance(time, h5py.Dataset) or time.ndim != 1:
        raise StoreError(f"{path}: missing or malformed dataset /reference/time")
    iterations = _require_group(handle, "iterations", path)
    complete: dict[int, str] = {}
    for name, group in iterations.items():
        if isinstance(group, h5py.Group) and _is_complete(group):
            try:
                complete[int(name)] = group.name
            except ValueError:
                raise StoreError(f"{path}: unexpected iteration group /iterations/{name}") from None
    ordered = tuple(sorted(complete))
    return _Layout(n_log=int(time.shape[0]), complete=ordered, groups={j: complete[j] for j in ordered})


def _validate_open(handle: h5py.File, path: Path) -> _Layout:
    """The structural checks of :func:`validate` on an open file whose header is checked."""
    reference = _require_group(handle, "reference", path)
    time = reference.get("time")
    if not isinstance(time, h5py.Dataset) or time.ndim != 1:
        raise StoreError(f"{path}: missing or malformed dataset /reference/time")
    n_log = int(time.shape[0])
    for name, (axes, _unit, _description) in REFERENCE_SIGNALS.items():
        _require_dataset(reference, name, (n_log,) if axes is None else (n_log, len(axes)), path)
    _check_units(reference, path)

    iterations = _require_group(handle, "iterations", path)
    complete: dict[int, str] = {}
    for name, group in iterations.items():
        if not isinstance(group, h5py.Group) or not _is_complete(group):
            continue  # an unfinished commit: ignored by readers
        try:
            j = int(name)
        except ValueError:
            raise StoreError(f"{path}: unexpected iteration group /iterations/{name}") from None
        missing = [attr for attr in ITERATION_ATTRS if attr not in group.attrs]
        if missing:
            raise StoreError(f"{path}: /iterations/{name} is missing attributes {', '.join(missing)}")
        if int(_py(group.attrs["iteration"])) != j:
            raise StoreError(f"{path}: /iterations/{name} has attribute iteration={_py(group.attrs['iteration'])}")
        log = _require_group(group, "log", path)
        for signal, (axes, _unit, _description) in LOG_SIGNALS.items():
            _require_dataset(log, signal, (n_log,) if axes is None else (n_log, len(axes)), path)
        _require_group(group, "memory", path)
        _check_units(group, path)
        complete[j] = group.name

    metrics = _require_group(handle, "metrics", path)
    lengths: dict[str, int] = {}
    for column in METRIC_COLUMNS:
        dataset = metrics.get(column)
        if not isinstance(dataset, h5py.Dataset) or dataset.ndim != 1:
            raise StoreError(f"{path}: missing or malformed metrics column /metrics/{column}")
        lengths[column] = int(dataset.shape[0])
    if len(set(lengths.values())) > 1:
        raise StoreError(
            f"{path}: metrics columns have different lengths ("
            + ", ".join(f"{c}={n}" for c, n in lengths.items())
            + ")"
        )
    _check_units(metrics, path)
    in_metrics = {int(j) for j in metrics["iteration"][()]}
    without_row = sorted(set(complete) - in_metrics)
    if without_row:
        raise StoreError(f"{path}: complete iteration {without_row[0]} has no row in /metrics")
    ordered = tuple(sorted(complete))
    return _Layout(n_log=n_log, complete=ordered, groups={j: complete[j] for j in ordered})


def validate(path: str | os.PathLike[str]) -> None:
    """Check that ``path`` is a readable ilcforce store; raise StoreError (one line) if not.

    Checks: the file exists and is not empty; HDF5 opens it; ``schema`` is ``ilcforce.store``
    with a major version not newer than :data:`SCHEMA_VERSION`; every root attribute of
    :data:`ROOT_ATTRS` is present and ``run_state`` is known; ``/reference`` holds every
    :data:`~ilcforce.records.REFERENCE_SIGNALS` entry with shape (n_log,) or (n_log, 2);
    every complete iteration group has its attributes and every
    :data:`~ilcforce.records.LOG_SIGNALS` dataset with shape (n_log,) or (n_log, 2) and a
    memory group; every dataset in ``/reference``, ``/metrics`` and the complete iterations
    has a ``units`` attribute; the ``/metrics`` columns all exist and have the same length and
    hold a row for every complete iteration. Incomplete iteration groups are ignored.
    """
    with _open_store(path) as (handle, checked_path):
        _validate_open(handle, checked_path)


def iterations(path: str | os.PathLike[str]) -> list[int]:
    """Complete iterations stored in ``path``, ascending."""
    with _open_store(path) as (handle, checked_path):
        return list(_scan(handle, checked_path).complete)


def read_provenance(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Root attributes as python types (str, int, float, bool, list), :data:`ROOT_ATTRS` first."""
    with _open_store(path) as (handle, checked_path):
        _scan(handle, checked_path)
        names = list(ROOT_ATTRS) + sorted(set(handle.attrs) - set(ROOT_ATTRS))
        out = {name: _py(handle.attrs[name]) for name in names}
    if out.get("run_state") == "running" and not writer_active(path):
        out["run_state"] = "partial"  # the writer was killed (kill -9, power loss) mid-run
    return out


def writer_active(path: str | os.PathLike[str]) -> bool:
    """True while a :class:`StoreWriter` holds ``<path>.lock`` (the flock dies with its process)."""
    lock = Path(path).with_name(f"{Path(path).name}.lock")
    try:
        fd = os.open(lock, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # closing releases a lock we took
    return False


def read_metrics(path: str | os.PathLike[str]) -> pd.DataFrame:
    """The metrics table of the complete iterations.

    Returns
    -------
    DataFrame
        Indexed by ``iteration`` (int), ascending; columns :data:`ilcforce.metrics.METRIC_COLUMNS`
        except ``iteration``, in that order (``status`` str, ``fallback_count`` int, the rest
        float). ``df.attrs["units"]`` maps column -> unit (``"-"`` for dimensionless),
        ``df.attrs["descriptions"]`` column -> description.
    """
    with _open_store(path) as (handle, checked_path):
        layout = _scan(handle, checked_path)
        metrics = handle["metrics"]
        iteration_column = metrics["iteration"][()].astype(np.int64)
        columns: dict[str, np.ndarray] = {}
        units: dict[str, str] = {}
        descriptions: dict[str, str] = {}
        for column in METRIC_COLUMNS:
            dataset = metrics[column]
            if column in _STR_METRICS:
                values = np.asarray(dataset.asstr()[()], dtype=object)
            else:
                values = dataset[()]
            if values.shape != iteration_column.shape:
                raise StoreError(f"{checked_path}: metrics columns have different lengths "
                                 f"(iteration={iteration_column.size}, {column}={values.size})")
            columns[column] = values
            units[column] = str(_py(dataset.attrs["units"]))
            descriptions[column] = str(_py(dataset.attrs.get("description", "")))
    # Keep the last row of each complete iteration (commits are atomic, so there is one).
    complete = set(layout.complete)
    rows: dict[int, int] = {int(j): k for k, j in enumerate(iteration_column) if int(j) in complete}
    order = [rows[j] for j in sorted(rows)]
    data = {
        column: values[order]
        for column, values in columns.items()
        if column != "iteration"
    }
    import pandas as pd

    frame = pd.DataFrame(data, index=pd.Index(np.asarray(sorted(rows), dtype=np.int64), name="iteration"))
    frame["status"] = frame["status"].astype(str)
    for column in _INT_METRICS:
        if column in frame:
            frame[column] = frame[column].astype(np.int64)
    frame.attrs["units"] = {column: units[column] for column in frame.columns}
    frame.attrs["descriptions"] = {column: descriptions[column] for column in frame.columns}
    return frame


def _group_for(layout: _Layout, j: int, path: Path) -> str:
    if j not in layout.groups:
        stored = f"{layout.complete[0]}..{layout.complete[-1]}" if layout.complete else "none"
        raise StoreError(f"{path}: iteration {j} is not stored (complete iterations: {stored})")
    return layout.groups[j]


def _frame_from_group(
    group: h5py.Group,
    signals: Mapping[str, tuple[tuple[str, ...] | None, str, str]],
    time: np.ndarray,
) -> pd.DataFrame:
    """DataFrame indexed by ``time`` with one column per signal axis; attrs["units"]."""
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {"time": "s"}
    for signal, (axes, _unit, _description) in signals.items():
        if signal == "time":
            continue
        dataset = group[signal]
        values = dataset[()]
        unit = str(_py(dataset.attrs["units"]))
        names = _column_names(signal, axes)
        if axes is None:
            data[names[0]] = values
        else:
            for column, name in enumerate(names):
                data[name] = values[:, column]
        for name in names:
            units[name] = unit
    import pandas as pd

    frame = pd.DataFrame(data, index=pd.Index(time, name="time"))
    frame.attrs["units"] = units
    return frame


def read_iteration(path: str | os.PathLike[str], j: int) -> pd.DataFrame:
    """The logged trajectories of iteration ``j``.

    Returns
    -------
    DataFrame, shape (n_log, 32)
        Index ``time`` (s): the iteration's logged time; samples after a divergence (NaN in the
        log) take the log-grid time from ``/reference/time`` so the index has no gaps. One
        column per signal axis of :data:`~ilcforce.records.LOG_SIGNALS`, named
        ``<signal>_<axis>`` (``position_x``, ``torque_1``) or ``<signal>`` for a scalar signal.
        ``df.attrs``: ``units`` (column -> unit, including ``time``), ``iteration``,
        ``status``, ``fallback_count``, ``diverged_time`` (s), ``diverged_reason``.
    """
    with _open_store(path) as (handle, checked_path):
        layout = _scan(handle, checked_path)
        group = handle[_group_for(layout, int(j), checked_path)]
        time = group["log/time"][()]
        reference_time = handle["reference/time"][()]
        time = np.where(np.isfinite(time), time, reference_time)
        frame = _frame_from_group(group["log"], LOG_SIGNALS, time)
        frame.attrs["iteration"] = int(_py(group.attrs["iteration"]))
        frame.attrs["status"] = str(_py(group.attrs["status"]))
        frame.attrs["fallback_count"] = int(_py(group.attrs["fallback_count"]))
        frame.attrs["diverged_time"] = float(_py(group.attrs["diverged_time"]))
        frame.attrs["diverged_reason"] = str(_py(group.attrs["diverged_reason"]))
    return frame


def read_memory(path: str | os.PathLike[str], j: int) -> dict[str, np.ndarray]:
    """Learned memory stored with iteration ``j`` (the memory iteration j + 1 starts from).

    Returns name -> float64 array, shape (n_control, ...), exact copies; empty for a
    memoryless controller.
    """
    with _open_store(path) as (handle, checked_path):
        layout = _scan(handle, checked_path)
        memory = handle[_group_for(layout, int(j), checked_path)]["memory"]
        return {name: np.array(dataset[()], dtype=np.float64) for name, dataset in memory.items()}


def read_memory_units(path: str | os.PathLike[str], j: int) -> dict[str, str]:
    """Units of the learned memory stored with iteration ``j``: name -> unit."""
    with _open_store(path) as (handle, checked_path):
        layout = _scan(handle, checked_path)
        memory = handle[_group_for(layout, int(j), checked_path)]["memory"]
        return {name: str(_py(dataset.attrs["units"])) for name, dataset in memory.items()}


def read_reference(path: str | os.PathLike[str]) -> pd.DataFrame:
    """The reference trajectories: DataFrame indexed by ``time`` (s), columns
    ``<signal>_<axis>`` of :data:`~ilcforce.records.REFERENCE_SIGNALS` (e.g.
    ``position_desired_x``), ``df.attrs["units"]`` column -> unit. Shape (n_log, 8)."""
    with _open_store(path) as (handle, checked_path):
        _scan(handle, checked_path)
        reference = handle["reference"]
        return _frame_from_group(reference, REFERENCE_SIGNALS, reference["time"][()])


def find_stores(results_dir: str | os.PathLike[str]) -> dict[str, dict[str, Path]]:
    """Every ``results_dir/<experiment>/<method>.h5``: experiment -> method -> path, sorted.

    Lock files (``*.h5.lock``) and leftover commit copies (``*.h5.tmp-<pid>``) are skipped.
    The files are not opened (use :func:`validate`). StoreError if ``results_dir`` is not a
    directory.
    """
    root = Path(results_dir)
    if not root.is_dir():
        raise StoreError(f"{root}: results directory does not exist or is not a directory")
    found: dict[str, dict[str, Path]] = {}
    for experiment_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        methods = {
            p.stem: p
            for p in sorted(experiment_dir.iterdir())
            if p.is_file() and p.suffix == ".h5" and not p.name.startswith(".")
        }
        if methods:
            found[experiment_dir.name] = methods
    return found


# ----------------------------------------------------------------------------------------------
# writing


def _config_difference(stored: Any, new: Any, tolerated: tuple[Any, Any], prefix: str = "") -> str | None:
    """Dotted path of the first leaf where two parsed JSON configs differ, or None.

    A leaf that changed from ``tolerated[0]`` to ``tolerated[1]`` (the number of iterations,
    old -> new) does not count as a difference, whatever its key is called.
    """
    if isinstance(stored, dict) and isinstance(new, dict):
        for key in sorted(set(stored) | set(new), key=str):
            where = f"{prefix}.{key}" if prefix else str(key)
            if key not in stored or key not in new:
                return where
            found = _config_difference(stored[key], new[key], tolerated, where)
            if found is not None:
                return found
        return None
    if isinstance(stored, list) and isinstance(new, list):
        if len(stored) != len(new):
            return prefix or "<root>"
        for index, (a, b) in enumerate(zip(stored, new)):
            found = _config_difference(a, b, tolerated, f"{prefix}[{index}]")
            if found is not None:
                return found
        return None
    if stored == new and type(stored) is type(new):
        return None
    if (stored, new) == tolerated and all(isinstance(v, int) and not isinstance(v, bool) for v in (stored, new)):
        return None
    return prefix or "<root>"


def _leaf(config: Any, where: str) -> str:
    """Short repr of the value at a dotted path produced by :func:`_config_difference`."""
    value = config
    try:
        for part in where.replace("[", ".[").split("."):
            if not part:
                continue
            value = value[int(part[1:-1])] if part.startswith("[") else value[part]
    except (KeyError, IndexError, TypeError, ValueError):
        return "<absent>"
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


class StoreWriter:
    """Writes one run into ``results/<experiment>/<method>.h5``, one atomic commit per iteration.

    Use as a context manager::

        with StoreWriter(path, experiment=..., method=..., config_toml=..., config_json=...,
                         seed=..., command=..., n_iterations=..., reference=...) as writer:
            memory = writer.resume_memory()            # {} on a fresh run
            if writer.stored_status() != "diverged":   # a resumed run that diverged is over
                for j in range(writer.last_complete_iteration + 1, n_iterations):
                    record = simulate_iteration(j, memory)
                    writer.append(record)
                    if record.diverged:
                        break
                    memory = record.memory
            writer.finish(writer.stored_status() or "complete")

    Leaving the block without :meth:`finish` (exception, Ctrl-C) sets run_state ``"partial"``.

    Parameters
    ----------
    path : path-like
        The store, ``results/<experiment>/<method>.h5``. Its parent directory is created.
    experiment, method : str
        Names stored as provenance (and compared on resume).
    config_toml, config_json : str
        Resolved configuration as TOML and JSON text. On resume the JSON must equal the stored
        one except for the number of iterations.
    seed : int
        Random seed of the run (compared on resume).
    command : str
        The command line that started the run.
    n_iterations : int
        Number of iterations requested (>= 0).
    reference : dict[str, ndarray]
        Every :data:`~ilcforce.records.REFERENCE_SIGNALS` entry on the log grid, shape
        (n_log,) for ``time``, (n_log, 2) otherwise. ``n_log`` fixes the log length every
        appended record must have. On resume it must equal the stored reference exactly.
    overwrite : bool
        Replace an existing file (atomically, at the first commit; until then the old file
        stays readable).
    resume : bool
        Continue an existing file after its last complete iteration (a missing file starts a
        fresh run).

    Raises (on enter)
    -----------------
    StoreLockedError
        Another writer holds ``<path>.lock``.
    StoreExistsError
        ``path`` exists and neither ``overwrite`` nor ``resume`` is set.
    StoreError
        The parent directory cannot be created or written, or the file to resume is invalid or
        belongs to a different experiment / method / seed / config / reference.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        experiment: str,
        method: str,
        config_toml: str,
        config_json: str,
        seed: int,
        command: str,
        n_iterations: int,
        reference: dict[str, np.ndarray],
        overwrite: bool = False,
        resume: bool = False,
    ) -> None:
        self._path = Path(path)
        if overwrite and resume:
            raise StoreError(f"{self._path}: --overwrite and --resume are mutually exclusive; choose one")
        if int(n_iterations) != n_iterations or n_iterations < 0:
            raise ValueError(f"n_iterations must be an int >= 0, got {n_iterations!r}")
        self._experiment = str(experiment)
        self._method = str(method)
        self._config_toml = str(config_toml)
        self._config_json = str(config_json)
        self._seed = int(seed)
        self._command = str(command)
        self._n_iterations = int(n_iterations)
        self._overwrite = bool(overwrite)
        self._resume = bool(resume)
        if "time" not in reference:
            raise ValueError("reference is missing signal 'time'")
        n_log = np.asarray(reference["time"]).shape[0] if np.ndim(reference["time"]) == 1 else -1
        if n_log < 2:
            raise ValueError(f"reference['time'] must have shape (n_log,) with n_log >= 2, got {np.shape(reference['time'])}")
        self._n_log = int(n_log)
        self._reference = {
            name: _signal_array(reference, "reference", name, axes, self._n_log).copy()
            for name, (axes, _unit, _description) in REFERENCE_SIGNALS.items()
        }
        unknown = sorted(set(reference) - set(REFERENCE_SIGNALS))
        if unknown:
            raise ValueError(f"reference has unknown signal {unknown[0]!r} (not in records.REFERENCE_SIGNALS)")
        self._lock_fd: int | None = None
        self._entered = False
        self._finished = False
        self._file_is_ours = False  # does ``path`` hold this run's data (resumed or committed)?
        self._appended = False
        self._last = -1
        self._last_status: str | None = None
        self._stored_run_state: str | None = None
        self._created_utc = _utc_now()
        self._shadow_ready = False  # does ``_tmp_path`` hold exactly the committed content?
        self._git_commit = ""

    # -- public properties ---------------------------------------------------------------

    @property
    def path(self) -> Path:
        """The store file."""
        return self._path

    @property
    def last_complete_iteration(self) -> int:
        """Last committed (or, on resume, stored) complete iteration; -1 if none."""
        return self._last

    def resume_memory(self) -> dict[str, np.ndarray]:
        """Memory stored with the last complete iteration (exact float64 copies, shape
        (n_control, ...)); ``{}`` if no iteration is stored or the controller has no memory."""
        self._require_open()
        if self._last < 0 or not self._file_is_ours:
            return {}
        return read_memory(self._path, self._last)

    def stored_status(self) -> str | None:
        """Status (``"complete"`` / ``"diverged"``) of the last complete iteration; None if none."""
        return self._last_status

    # -- context management --------------------------------------------------------------

    def __enter__(self) -> StoreWriter:
        if self._entered:
            raise RuntimeError("a StoreWriter can be entered only once")
        self._make_parent()
        self._acquire_lock()
        try:
            self._remove_stale_copies()
            self._git_commit = _git_commit()
            if self._path.exists():
                if self._resume:
                    self._load_for_resume()
                elif not self._overwrite:
                    raise StoreExistsError(
                        f"{self._path} already exists ({self._describe_existing()}); "
                        "--overwrite replaces it or --resume continues it"
                    )
        except BaseException:
            self._release_lock()
            raise
        self._entered = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        try:
            if (
                not self._finished
                and self._file_is_ours
                and self._last >= 0
                and (self._appended or self._stored_run_state == "running")
            ):
                now = _utc_now()
                try:
                    self._commit(lambda handle: self._set_run_state(handle, "partial", now), lambda: None)
                except Exception:
                    if exc_type is None:
                        raise
                    # Keep the original exception; the file still validates (state "running").
        finally:
            self._tmp_path.unlink(missing_ok=True)
            self._previous_path.unlink(missing_ok=True)
            self._shadow_ready = False
            self._release_lock()
            self._entered = False

    # -- writing -------------------------------------------------------------------------

    def append(self, record: IterationRecord) -> None:
        """Commit one iteration atomically (see the module docstring).

        ``record.iteration`` must be ``last_complete_iteration + 1`` (StoreError otherwise);
        its ``log`` must hold exactly the :data:`~ilcforce.records.LOG_SIGNALS` with
        ``n_log`` samples and every ``memory`` entry needs a unit in ``memory_units``
        (ValueError otherwise).
        """
        self._require_open()
        if self._finished:
            raise StoreError(f"{self._path}: run already finished; cannot append iteration {record.iteration}")
        if record.iteration != self._last + 1:
            raise StoreError(
                f"{self._path}: cannot append iteration {record.iteration}: the last complete iteration is "
                f"{self._last}, so the next must be {self._last + 1}"
            )
        log, memory, row = self._check_record(record)

        def write(handle: h5py.File) -> None:
            name = f"iterations/{record.iteration:04d}"
            if name in handle:  # an unfinished group (ignored by readers): replace it
                del handle[name]
            group = handle.create_group(name)
            group.attrs["iteration"] = int(record.iteration)
            group.attrs["status"] = str(record.status)
            group.attrs["diverged_time"] = float(record.diverged_time)
            group.attrs["diverged_reason"] = _one_line(record.diverged_reason)
            group.attrs["fallback_count"] = int(record.fallback_count)
            log_group = group.create_group("log")
            for signal, (axes, unit, description) in LOG_SIGNALS.items():
                _describe(log_group.create_dataset(signal, data=log[signal]), unit, description, axes)
            memory_group = group.create_group("memory")
            for key, values in memory.items():
                dataset = memory_group.create_dataset(key, data=values)
                dataset.attrs["units"] = str(record.memory_units[key])
                dataset.attrs["description"] = (
                    f"learned memory {key} after iteration {record.iteration} (the memory iteration "
                    f"{record.iteration + 1} starts from), on the control grid"
                )
            metrics = handle["metrics"]
            for column, value in row.items():
                dataset = metrics[column]
                n = dataset.shape[0]
                dataset.resize((n + 1,))
                dataset[n] = value
            if first_of_session:  # provenance of this invocation (refreshes a resumed file)
                self._write_invocation_attrs(handle)
            self._set_run_state(handle, "running", now)
            group.attrs["complete"] = True  # last: marks the iteration as readable

        def committed() -> None:
            self._appended = True
            self._last = int(record.iteration)
            self._last_status = str(record.status)

        # ``write`` runs twice (the commit copy, then the shadow): everything it writes is fixed here.
        first_of_session = not self._appended
        now = _utc_now()
        self._commit(write, committed)

    def finish(self, status: str) -> None:
        """Mark the run ``"complete"`` or ``"diverged"`` (run_state; committed atomically)."""
        self._require_open()
        if status not in (STATUS_COMPLETE, STATUS_DIVERGED):
            raise ValueError(f"status must be {STATUS_COMPLETE!r} or {STATUS_DIVERGED!r}, got {status!r}")
        if not self._file_is_ours or self._last < 0:
            raise StoreError(f"{self._path}: cannot finish a run with no stored iteration")
        now = _utc_now()
        self._commit(lambda handle: self._set_run_state(handle, status, now), self._mark_finished)

    def _mark_finished(self) -> None:
        self._finished = True

    # -- internals -----------------------------------------------------------------------

    @property
    def _tmp_path(self) -> Path:
        return self._path.with_name(f"{self._path.name}.tmp-{os.getpid()}")

    @property
    def _previous_path(self) -> Path:
        return self._path.with_name(f"{self._path.name}.tmp-{os.getpid()}.prev")

    @property
    def _lock_path(self) -> Path:
        return self._path.with_name(f"{self._path.name}.lock")

    def _require_open(self) -> None:
        if not self._entered:
            raise RuntimeError("StoreWriter must be used as a context manager ('with StoreWriter(...) as writer')")

    def _make_parent(self) -> None:
        parent = self._path.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as error:
            raise StoreError(f"{self._path}: cannot create directory {parent} ({error.strerror or error})") from None
        if not os.access(parent, os.W_OK | os.X_OK):
            raise StoreError(f"{self._path}: directory {parent} is not writable")

    def _acquire_lock(self) -> None:
        try:
            fd = os.open(self._lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:
            raise StoreError(f"{self._path}: cannot open lock file {self._lock_path} ({error.strerror or error})") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(fd)
            if error.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise StoreLockedError(
                    f"{self._path} is being written by another ilcforce process; "
                    "wait for it to finish or choose another --out"
                ) from None
            raise StoreError(f"{self._path}: cannot lock {self._lock_path} ({error.strerror or error})") from None
        try:  # record the holder, for humans looking at a stuck lock
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass
        self._lock_fd = fd

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            try:
                fcntl.flock(self._lock_fd, fcntl.LOCK_UN)
            finally:
                os.close(self._lock_fd)
                self._lock_fd = None

    def _remove_stale_copies(self) -> None:
        """Delete ``<path>.tmp-*`` left by a killed writer (we hold the lock: none is live)."""
        for stale in self._path.parent.glob(f"{self._path.name}.tmp-*"):
            try:
                stale.unlink()
            except OSError:
                pass

    def _describe_existing(self) -> str:
        try:
            provenance = read_provenance(self._path)
            done = iterations(self._path)
        except StoreError as error:
            return f"not a valid store: {error}"
        return f"run_state {provenance['run_state']!r}, {len(done)} complete iterations"

    def _load_for_resume(self) -> None:
        validate(self._path)
        provenance = read_provenance(self._path)
        for key, new in (("experiment", self._experiment), ("method", self._method), ("seed", self._seed)):
            if provenance[key] != new:
                raise StoreError(
                    f"{self._path}: cannot resume: stored {key} is {provenance[key]!r}, this run has {new!r}; "
                    "use --overwrite to start again"
                )
        stored_json = str(provenance["config_json"])
        try:
            stored_config, new_config = json.loads(stored_json), json.loads(self._config_json)
        except json.JSONDecodeError:
            stored_config, new_config = stored_json, self._config_json
        tolerated = (int(provenance["n_iterations_requested"]), self._n_iterations)
        where = _config_difference(stored_config, new_config, tolerated)
        if where is not None:
            raise StoreError(
                f"{self._path}: cannot resume: configuration differs from the stored run at {where!r} "
                f"(stored {_leaf(stored_config, where)}, new {_leaf(new_config, where)}); "
                "use --overwrite to start again"
            )
        stored_reference = read_reference(self._path)
        for name, (axes, _unit, _description) in REFERENCE_SIGNALS.items():
            if name == "time":
                stored = stored_reference.index.to_numpy(dtype=np.float64)
            else:
                stored = stored_reference[_column_names(name, axes)].to_numpy(dtype=np.float64)
                if axes is None:
                    stored = stored[:, 0]
            if stored.shape != self._reference[name].shape or not np.array_equal(
                stored, self._reference[name], equal_nan=True
            ):
                raise StoreError(
                    f"{self._path}: cannot resume: reference signal {name!r} differs from the stored one; "
                    "use --overwrite to start again"
                )
        done = iterations(self._path)
        self._file_is_ours = True
        self._stored_run_state = str(provenance["run_state"])
        if done:
            self._last = done[-1]
            self._last_status = str(read_iteration(self._path, self._last).attrs["status"])

    def _check_record(
        self, record: IterationRecord
    ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, object]]:
        """Float64 log and memory arrays and the metrics row of a record; ValueError if malformed."""
        if record.status not in (STATUS_COMPLETE, STATUS_DIVERGED):
            raise ValueError(f"record.status must be {STATUS_COMPLETE!r} or {STATUS_DIVERGED!r}, got {record.status!r}")
        unknown = sorted(set(record.log) - set(LOG_SIGNALS))
        if unknown:
            raise ValueError(f"record.log has unknown signal {unknown[0]!r} (not in records.LOG_SIGNALS)")
        log = {
            name: _signal_array(record.log, "record.log", name, axes, self._n_log)
            for name, (axes, _unit, _description) in LOG_SIGNALS.items()
        }
        memory: dict[str, np.ndarray] = {}
        for key, values in record.memory.items():
            if not key or "/" in key or key == ".":
                raise ValueError(f"record.memory key {key!r} is not a valid dataset name")
            if key not in record.memory_units:
                raise ValueError(f"record.memory_units has no unit for memory {key!r}")
            array = np.asarray(values, dtype=np.float64)
            if array.ndim < 1:
                raise ValueError(f"record.memory[{key!r}] must be (n_control, ...), got a scalar")
            memory[key] = array
        return log, memory, iteration_metrics(record)

    def _initialise(self, handle: h5py.File) -> None:
        """Root attributes, /reference and the empty /metrics columns of a new file."""
        attrs = handle.attrs
        attrs["schema"] = SCHEMA_NAME
        attrs["schema_version"] = SCHEMA_VERSION
        attrs["ilcforce_version"] = str(ilcforce.__version__)
        attrs["git_commit"] = self._git_commit
        attrs["created_utc"] = self._created_utc
        attrs["updated_utc"] = self._created_utc
        attrs["experiment"] = self._experiment
        attrs["method"] = self._method
        attrs["seed"] = self._seed
        attrs["run_state"] = "running"
        self._write_invocation_attrs(handle)
        reference = handle.create_group("reference")
        for name, (axes, unit, description) in REFERENCE_SIGNALS.items():
            _describe(reference.create_dataset(name, data=self._reference[name]), unit, description, axes)
        handle.create_group("iterations")
        metrics = handle.create_group("metrics")
        for column, (unit, description) in METRIC_COLUMNS.items():
            if column in _STR_METRICS:
                dtype: Any = h5py.string_dtype("utf-8")
            elif column in _INT_METRICS:
                dtype = np.int64
            else:
                dtype = np.float64
            dataset = metrics.create_dataset(
                column, shape=(0,), maxshape=(None,), chunks=(_METRICS_CHUNK,), dtype=dtype
            )
            dataset.attrs["units"] = unit
            dataset.attrs["description"] = description

    def _write_invocation_attrs(self, handle: h5py.File) -> None:
        """Provenance of the current invocation (also refreshed by the first commit of a resume)."""
        handle.attrs["command"] = self._command
        handle.attrs["config_toml"] = self._config_toml
        handle.attrs["config_json"] = self._config_json
        handle.attrs["n_iterations_requested"] = self._n_iterations

    @staticmethod
    def _set_run_state(handle: h5py.File, state: str, now: str) -> None:
        handle.attrs["run_state"] = state
        handle.attrs["updated_utc"] = now

    def _commit(self, change: Callable[[h5py.File], None], committed: Callable[[], None]) -> None:
        """Apply ``change`` to a copy of the store (or to a new file) and rename it over ``path``.

        ``change`` must be deterministic (it is applied again to the shadow copy). ``committed``
        runs right after the rename, before the shadow is refreshed, so the writer's bookkeeping
        is right even if the refresh is interrupted.
        """
        tmp, previous = self._tmp_path, self._previous_path
        had_file = self._file_is_ours
        keep_previous = False
        try:
            if had_file:
                if not self._shadow_ready:
                    shutil.copyfile(self._path, tmp)
                self._shadow_ready = False  # tmp now diverges from the committed file
                with h5py.File(tmp, "a") as handle:
                    change(handle)
            else:
                with h5py.File(tmp, "w") as handle:
                    self._initialise(handle)
                    change(handle)
            if had_file and _shadow_allowed():
                previous.unlink(missing_ok=True)
                try:
                    os.link(self._path, previous)
                    keep_previous = True
                except OSError:  # no hard links here: fall back to copying
                    keep_previous = False
            os.replace(tmp, self._path)  # the commit
        except BaseException as error:
            tmp.unlink(missing_ok=True)
            previous.unlink(missing_ok=True)
            if isinstance(error, OSError):
                raise StoreError(f"{self._path}: cannot commit ({_one_line(error)})") from error
            raise
        self._file_is_ours = True
        committed()
        if keep_previous:
            self._refresh_shadow(change)

    def _refresh_shadow(self, change: Callable[[h5py.File], None]) -> None:
        """Bring the previous committed file (hard-linked at ``_previous_path``) up to date and
        keep it as the next commit's copy; on any failure drop it (the next commit copies)."""
        tmp, previous = self._tmp_path, self._previous_path
        try:
            # locking=True: refuse if a reader that opened it before the rename still has it open.
            with h5py.File(previous, "a", locking=True) as handle:
                change(handle)
            os.replace(previous, tmp)
        except Exception:
            previous.unlink(missing_ok=True)
            return
        except BaseException:
            previous.unlink(missing_ok=True)
            raise
        self._shadow_ready = True


def _shadow_allowed() -> bool:
    """Can HDF5 locks tell whether an old store file is still open (see the module docstring)?"""
    setting = os.environ.get("HDF5_USE_FILE_LOCKING")
    return setting is None or setting.strip().upper() in ("TRUE", "1")
