"""The store's layout as data: what every attribute and dataset is, its type and its shape.

Readers, :func:`ilcforce.store.validate` and the writer all use these tables; the module docstring
of :mod:`ilcforce.store` explains the layout in prose.

Schema ``ilcforce.store`` version ``2.2`` (2.1: no bindings; 2.0: no attribute seals either). A
reader refuses a file whose major version is newer than its own. Version 1.x files (written before
the rebuild: no checksums, HDF5 1.6 metadata without checksums) are still read; see
:mod:`ilcforce.store.safeio` for how they are opened.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

# the names results and report folders hold: the configuration's rule, read by the store too
from ilcforce.config_ranges import REPORT_MARKER, RESERVED_NAMES, STUDY_NAME, experiment_name_problem  # noqa: F401
from ilcforce.records import LOG_SIGNALS, REFERENCE_SIGNALS, TASK_DIMENSIONS, log_signals, reference_signals

SCHEMA_NAME = "ilcforce.store"
#: The study store's schema name (ilcforce/store/study.py); here so that a run-store reader can name it.
STUDY_SCHEMA_NAME = "ilcforce.study"
SCHEMA_VERSION = "2.2"
#: From this schema version on, every object with attributes carries ``attrs_crc32``
#: (:mod:`ilcforce.store.seal`). A 2.0 store has none: it is read, and ``validate`` says that its
#: metadata is unverified (accepted, not refused: its data is still checksummed, and refusing it
#: would lose every store written before the seals; a rerun with --overwrite seals it).
SEALED_FROM = (2, 1)
#: From this schema version on, a store has a random ``store_id`` and binds every record to it and to
#: its place (:mod:`ilcforce.store.binding`). A 2.1 store has none: it is read, and ``validate`` says
#: that its records are not bound (a record copied from another store is not detected in it); a
#: 2.1 store carrying a binding, or a 2.2 store missing one, is refused.
BOUND_FROM = (2, 2)
#: A method name as stored (it names the store file ``<method>.h5``): never a path.
METHOD_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")


def is_plain_name(text: str) -> bool:
    """A name that makes one results folder, never a path (an experiment's, as stored)."""
    return experiment_name_problem(text) is None


#: HDF5 file-format bounds: "v108" gives version-2 object headers and superblock, whose metadata
#: blocks carry checksums, so a damaged block is an error instead of an endless walk.
LIBVER = ("v108", "latest")

RUN_STATES = ("running", "partial", "complete", "diverged")
ITERATION_STATUSES = ("complete", "diverged")

#: kinds of attribute values: "str", "int", "float", "bool", "str_list"
_KINDS = ("str", "int", "float", "bool", "str_list")


@dataclass(frozen=True)
class AttrSpec:
    """One attribute: its kind and what it means."""

    kind: str
    description: str
    required: bool = True


#: Root attributes.
ROOT_ATTRIBUTES: dict[str, AttrSpec] = {
    "schema": AttrSpec("str", "always 'ilcforce.store'"),
    "schema_version": AttrSpec("str", "'major.minor'"),
    "ilcforce_version": AttrSpec("str", "ilcforce.__version__ of the writer"),
    "git_commit": AttrSpec("str", "git rev-parse HEAD of the writer's checkout ('' if unknown)"),
    "git_dirty": AttrSpec("bool", "the checkout had uncommitted changes", required=False),
    "created_utc": AttrSpec("str", "ISO 8601 UTC time the run was first opened"),
    "updated_utc": AttrSpec("str", "ISO 8601 UTC time of the last commit"),
    "command": AttrSpec("str", "command line of the latest invocation"),
    "experiment": AttrSpec("str", "experiment name"),
    "method": AttrSpec("str", "method (controller) name"),
    "seed": AttrSpec("int", "random seed"),
    "config_toml": AttrSpec("str", "resolved configuration, TOML"),
    "config_json": AttrSpec("str", "resolved configuration, JSON"),
    "run_state": AttrSpec("str", "'running' | 'partial' | 'complete' | 'diverged'"),
    "n_iterations_requested": AttrSpec("int", "iterations asked for by the latest invocation"),
    "store_id": AttrSpec("str", "random identity made with the store (schema 2.2 on): the key of its "
                         "records' bindings", required=False),
    "n_iterations_stored": AttrSpec("int", "iterations the store holds, 0 .. n - 1 (schema 2.2 on)", required=False),
}
ROOT_ATTRS = tuple(ROOT_ATTRIBUTES)

#: Root attribute holding a run's task dimension n (int, 3): the store's task-space and joint-space
#: datasets are (n_log, n) with axes :func:`ilcforce.records.task_axes` / ``joint_axes`` of n, and its
#: /metrics has :func:`ilcforce.metrics.metric_columns` of n. Written only when n is not 2: a store
#: without it is a 2-axis store (every store written before n axes, and every 2-axis store since,
#: byte for byte as before). Not in :data:`ROOT_ATTRIBUTES`, whose names every store holds in order.
#: Readers check it against the width of ``/reference/force_desired``.
TASK_DIMENSION_ATTR = "task_dimension"
#: The task dimension of a store without :data:`TASK_DIMENSION_ATTR`.
DEFAULT_TASK_DIMENSION = 2

#: Attributes of every complete iteration group ``/iterations/<jjjj>``.
ITERATION_ATTRIBUTES: dict[str, AttrSpec] = {
    "iteration": AttrSpec("int", "j, equal to the group name"),
    "status": AttrSpec("str", "'complete' | 'diverged'"),
    "diverged_time": AttrSpec("float", "time (s) the watchdog stopped the iteration; NaN if complete"),
    "diverged_reason": AttrSpec("str", "watchdog rule that fired; '' if complete"),
    "fallback_count": AttrSpec("int", "samples where the implicit scheme reused the previous acceleration"),
    "complete": AttrSpec("bool", "written last: the group is readable"),
}
ITERATION_ATTRS = tuple(ITERATION_ATTRIBUTES)


def signal_shape(axes: tuple[str, ...] | None, n: int) -> tuple[int, ...]:
    """Shape of a signal dataset on a grid of ``n`` samples."""
    return (n,) if axes is None else (n, len(axes))


#: Datasets: group -> name -> (axes, unit, description); shapes from :func:`signal_shape` on the
#: log grid (``n_log = len(/reference/time)``). All float64; the reference Fletcher-32 checksummed, an
#: iteration's log by the CRC-32s in its group (:mod:`ilcforce.store.template`). These are a
#: 2-axis store's; :func:`reference_datasets` and :func:`log_datasets` give a store's of n axes.
REFERENCE_DATASETS = REFERENCE_SIGNALS
LOG_DATASETS = LOG_SIGNALS


def reference_datasets(n: int) -> dict[str, tuple[tuple[str, ...] | None, str, str]]:
    """The /reference datasets of a store of ``n`` task axes (:data:`REFERENCE_DATASETS` for 2)."""
    return reference_signals(n)


def log_datasets(n: int) -> dict[str, tuple[tuple[str, ...] | None, str, str]]:
    """The ``log/`` datasets of an iteration of a store of ``n`` task axes (:data:`LOG_DATASETS` for 2)."""
    return log_signals(n)


def known_dimension(value: Any) -> bool:
    """Whether a :data:`TASK_DIMENSION_ATTR` value is an int of :data:`ilcforce.records.TASK_DIMENSIONS`."""
    return kind_matches(value, "int") and not isinstance(value, (bool, np.bool_)) and int(value) in TASK_DIMENSIONS

#: Learned memory ``/iterations/<jjjj>/memory/<name>``: float64, (n_control,) or
#: (n_control, width); attrs ``units``, ``description`` and, for a matrix, ``columns``
#: (its column labels, e.g. Theta_hat's ``D11 D12 C11 C12 ...``). ``/control_time`` is the
#: control grid (n_control,), s.
CONTROL_TIME = "control_time"

#: Every dataset carries these attributes.
DATASET_ATTRS = ("units", "description")

#: Dataset creation options of the datasets written once or appended to (the reference, the control grid,
#: /metrics): one chunk per dataset, Fletcher-32. An iteration's datasets are not filtered: their
#: checksums are CRC-32s in the iteration group (:mod:`ilcforce.store.template`).
#: Compression: measured off (see the README's Store section: gzip cut the paper's store by
#: a few percent for several times the write time, because the logged noise is incompressible).
DATASET_OPTIONS: dict[str, Any] = {"fletcher32": True}

#: ``/metrics`` is a cache of :func:`ilcforce.metrics.iteration_metrics` over the stored logs. Its
#: group attrs: ``metrics_version`` (``ilcforce.metrics.METRICS_VERSION`` of the writer). A reader
#: whose version or columns differ recomputes the table from the logs; validation never fails on
#: a stale cache.
METRICS_GROUP = "metrics"


def kind_of(value: Any) -> str | None:
    """The attribute kind of an h5py attribute value, or None if it is none of the known kinds."""
    if isinstance(value, (bytes, str)):
        return "str"
    if isinstance(value, (bool, np.bool_)):
        return "bool"
    if isinstance(value, (int, np.integer)):
        return "int"
    if isinstance(value, (float, np.floating)):
        return "float"
    if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind in "SUO":
        return "str_list"
    return None


def kind_matches(value: Any, kind: str) -> bool:
    """Does an attribute value have ``kind`` (an int is accepted where a float is expected)?"""
    found = kind_of(value)
    if kind == "float":
        return found in ("float", "int")
    if kind == "bool":
        return found in ("bool", "int") and int(value) in (0, 1)
    return found == kind


def parse_version(text: str) -> tuple[int, int]:
    """``"major.minor"`` -> (major, minor); ValueError if malformed."""
    major, minor = str(text).split(".")
    return int(major), int(minor)
