"""The ``/metrics`` cache of a run store: created with the store, rows appended at the run's end.

One dataset per column of :func:`ilcforce.metrics.metric_columns` of the store's task dimension
(:data:`ilcforce.metrics.METRIC_COLUMNS` for 2 axes), one row per committed
iteration (chunked, resizable, Fletcher-32), each with ``units`` and ``description``; the group's
``metrics_version`` says which :func:`ilcforce.metrics.iteration_metrics` made them (readers
recompute the rows from the logs when it differs, or when rows are missing).

Rows are appended through h5py's low-level API (H5Dset_extent, a hyperslab, H5Dwrite): about a
quarter of the cost of ``Dataset.resize`` and ``dataset[n:] = values`` (1.8 against 7 ms for the 24
columns, measured), and it is paid in the run's last commit, after the last iteration has simulated
The stored values are those of the high-level calls (the tests read them back).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

import h5py
import numpy as np

from ilcforce.metrics import METRICS_VERSION, column_kind, metric_columns
from ilcforce.store import schema
from ilcforce.store.seal import seal_attrs

CHUNK_ROWS = 64  # rows per chunk of a /metrics column
_STR_BYTES = 16  # the status column: fixed-length UTF-8

_DESCRIPTION = ("cache of ilcforce.metrics.iteration_metrics over the stored logs, one row per committed "
                "iteration; recomputed by readers when its version differs")


def _columns(dimension: int) -> dict[str, tuple[str, str]]:
    return metric_columns(dimension)


def dimension_of(handle: h5py.File) -> int:
    """The task dimension a writer gave ``handle`` (its root attribute task_dimension; absent: 2)."""
    return int(handle.attrs.get(schema.TASK_DIMENSION_ATTR, schema.DEFAULT_TASK_DIMENSION))


def create(handle: h5py.File, dimension: int = schema.DEFAULT_TASK_DIMENSION) -> None:
    """Create an empty ``/metrics`` group of the current version, with the columns of a task of
    ``dimension`` axes, in ``handle``: copied (HDF5's H5Ocopy, attributes included, in C) from a
    group built once per process in memory, 0.3 against 5.5 ms for its 24 datasets and 50
    attributes (measured), in a new store's first commit."""
    h5py.h5o.copy(_template(dimension).id, schema.METRICS_GROUP.encode(), handle.id, schema.METRICS_GROUP.encode())


@functools.cache
def _template(dimension: int = schema.DEFAULT_TASK_DIMENSION) -> h5py.File:
    """An in-memory HDF5 file holding an empty ``/metrics`` group (:func:`_build`)."""
    template = h5py.File(f"ilcforce-metrics-template-{dimension}", "w", driver="core", backing_store=False,
                         libver=schema.LIBVER)
    _build(template, dimension)
    return template


def _build(handle: h5py.File, dimension: int = schema.DEFAULT_TASK_DIMENSION) -> None:
    """Make the empty ``/metrics`` group: one resizable column per metric, with its attributes."""
    metrics = handle.create_group(schema.METRICS_GROUP)
    metrics.attrs["metrics_version"] = METRICS_VERSION
    metrics.attrs["description"] = _DESCRIPTION
    for column, (unit, description) in _columns(dimension).items():
        kind = column_kind(column)
        dtype: Any = {"str": h5py.string_dtype("utf-8", _STR_BYTES), "int": np.int64, "float": np.float64}[kind]
        dataset = metrics.create_dataset(column, shape=(0,), maxshape=(None,), chunks=(CHUNK_ROWS,),
                                         dtype=dtype, **schema.DATASET_OPTIONS)
        dataset.attrs["units"] = unit
        dataset.attrs["description"] = description
        seal_attrs(dataset)
    seal_attrs(metrics)


def _is_current(handle: h5py.File, dimension: int) -> bool:
    """True if ``/metrics`` is a group of the current version holding a dataset per column of a
    task of ``dimension`` axes."""
    metrics = handle.get(schema.METRICS_GROUP)
    if not isinstance(metrics, h5py.Group) or metrics.attrs.get("metrics_version") != METRICS_VERSION:
        return False
    try:
        return all(h5py.h5o.get_info(metrics.id, column.encode()).type == h5py.h5o.TYPE_DATASET
                   for column in _columns(dimension))
    except KeyError:  # a column missing
        return False


def _column(values: list, kind: str) -> np.ndarray:
    if kind == "str":
        return np.array([str(v).encode("utf-8") for v in values], dtype=f"S{_STR_BYTES}")
    return np.array(values, dtype=np.int64 if kind == "int" else np.float64)


def append_rows(handle: h5py.File, rows: Sequence[dict[str, object]]) -> None:
    """Append ``rows`` (metrics rows, one per iteration) to ``/metrics``, skipping iterations it
    already holds; a missing or outdated group is made anew first (its rows are then recomputed
    by readers from the logs). The columns are those of the store's task dimension (:func:`dimension_of`)."""
    dimension = dimension_of(handle)
    if not _is_current(handle, dimension):
        if schema.METRICS_GROUP in handle:
            del handle[schema.METRICS_GROUP]
        create(handle, dimension)
    group = h5py.h5g.open(handle.id, schema.METRICS_GROUP.encode())
    iteration = h5py.h5d.open(group, b"iteration")
    stored = np.empty(iteration.shape, dtype=np.int64)
    if stored.size:
        iteration.read(h5py.h5s.ALL, h5py.h5s.ALL, stored)
    known = set(stored.tolist())
    rows = [row for row in rows if int(row["iteration"]) not in known]
    if not rows:
        return
    for column in _columns(dimension):
        kind = column_kind(column)
        data = _column([row[column] for row in rows], kind)
        dataset = h5py.h5d.open(group, column.encode())
        n = dataset.shape[0]
        dataset.set_extent((n + len(rows),))
        space = dataset.get_space()
        space.select_hyperslab((n,), (len(rows),))
        dataset.write(h5py.h5s.create_simple((len(rows),)), space, data,
                      mtype=dataset.get_type() if kind == "str" else None)
