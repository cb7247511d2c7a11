"""The results stores: runs, studies and tunings, one durability model (docs/store-format.md has
each layout and what protects each byte).

The only package that imports h5py. Modules, one job each: :mod:`.filecheck` (errors, what a path
is, opening damaged files in bounded time), :mod:`.safeio` (the writers' lock of every store,
interrupted commits), :mod:`.seal` (checksums over attributes, strings and numeric columns),
:mod:`.records` (sealed JSON records: whole-or-absent writes, bounded reads, quarantine),
:mod:`.binding` (what ties each record to its store and place, so a spliced one is refused),
:mod:`.schema` (the run layout as data, versioned), :mod:`.journal` and :mod:`.commit` (a run's
atomic commits), :mod:`.read` and :mod:`.access` (reading and validation), :mod:`.write` (the run
writer) and :mod:`.prepare` (its checks of the path before the first commit), :mod:`.run` (the
``ilcforce.open`` run object); the study store: :mod:`.study_read`, :mod:`.study` (its writer) and
:mod:`.study_journal` (its journal's records, checked); the tuning store: :mod:`.tuning`.

Crash safety: each run iteration, study cell and tuning trial is one atomic commit: kill -9,
Ctrl-C, a full disk leave every finished one. A second writer is refused. Errors are one line
naming the file and the problem.
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
