"""The HDF5 results store: one self-describing file per (experiment, method).

The only package that imports h5py. One file per run: ``results/<experiment>/<method>.h5``.
Modules, one job each: :mod:`.filecheck` (errors, what a path is, opening damaged files in
bounded time), :mod:`.safeio` (locks, interrupted commits), :mod:`.seal` (checksums over
attributes and strings), :mod:`.schema` (the layout as data, versioned), :mod:`.journal` and
:mod:`.commit` (atomic commits), :mod:`.read` and :mod:`.access` (reading and validation),
:mod:`.write` (the writer) and :mod:`.prepare` (its checks of the path before the first commit),
:mod:`.run` (the ``ilcforce.open`` run object); the study store: :mod:`.study_read`,
:mod:`.study` (its writer) and :mod:`.study_journal` (its journal's records, checked).

Layout (schema ``ilcforce.store`` 2.1; every dataset float64 unless stated, Fletcher-32
checksummed, with ``units`` and ``description`` attributes; every object's attributes sealed by
``attrs_crc32``, :mod:`.seal`)::

    /                       root attrs: schema.ROOT_ATTRIBUTES (provenance, config, run_state)
    /reference/<signal>     records.REFERENCE_SIGNALS on the log grid, attr axes
    /control_time           the control grid (s), the time axis of the learned memory
    /iterations/<jjjj>/     attrs: schema.ITERATION_ATTRIBUTES ("complete" written last)
        log/<signal>        records.LOG_SIGNALS on the log grid, (n_log,) or (n_log, 2), attr axes
        memory/<name>       learned memory after iteration j, (n_control,) or (n_control, width),
                            attr columns (e.g. Theta_hat's D11 D12 C11 C12 ...)
    /metrics/<column>       cache of metrics.iteration_metrics, one row per committed iteration,
                            group attr metrics_version; recomputed from the logs when stale

Crash safety: each iteration is one atomic commit (:mod:`.commit`): kill -9, Ctrl-C, a full disk
leave the store with every finished iteration. A second writer is refused. Errors are
:class:`StoreError`, one line naming the file and the problem.
"""

import importlib

from ilcforce.store.safeio import StoreError, StoreExistsError, StoreLockedError, writer_active
from ilcforce.store.schema import ITERATION_ATTRS, ROOT_ATTRS, RUN_STATES, SCHEMA_NAME, SCHEMA_VERSION

#: the names that need h5py, imported on first use: the errors above cost no h5py import (a
#: command's error handling imports them before anything else)
_LAZY = {
    **dict.fromkeys(("find_stores", "iterations", "read_control_time", "read_iteration", "read_memory",
                     "read_memory_info", "read_memory_units", "read_metrics", "read_metrics_rows", "read_provenance",
                     "read_reference",
                     "validate"), "ilcforce.store.access"),
    "StoreWriter": "ilcforce.store.write",
}


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = [
    "ITERATION_ATTRS", "ROOT_ATTRS", "RUN_STATES", "SCHEMA_NAME", "SCHEMA_VERSION", "StoreError",
    "StoreExistsError", "StoreLockedError", "StoreWriter", "find_stores", "iterations",
    "read_control_time", "read_iteration", "read_memory", "read_memory_info", "read_memory_units",
    "read_metrics", "read_metrics_rows", "read_provenance", "read_reference", "validate", "writer_active",
]
