"""Reading and validating stores. Every reader opens through :func:`open_store`.

:func:`validate` reads everything (so every checksum is verified: HDF5's Fletcher-32, the iterations'
CRC-32s, the attribute seals and the bindings of :mod:`.binding`) and checks the
type and shape of everything a reader uses. The other readers check only what they read (cheap:
a report reads hundreds of stores), but a wrong type or shape met while reading is still a
one-line :class:`StoreError`, never a traceback.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from time import sleep
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

if TYPE_CHECKING:  # pandas only where a frame is built: writing a run imports none
    import pandas as pd

from ilcforce.metrics import METRICS_VERSION, column_kind, iteration_metrics, metric_columns
from ilcforce.records import IterationRecord
from ilcforce.store import schema
from ilcforce.store.seal import ATTRS_SEAL, attrs_state
from ilcforce.store.template import verify
from ilcforce.store.safeio import (IS_A_STUDY_STORE, StoreError, one_line, probe,
                                   read_locked, superblock_version, writer_active)

_H5_ERRORS = (OSError, KeyError, ValueError, TypeError, RuntimeError, AttributeError, IndexError)


def py(value: Any) -> Any:
    """An HDF5 attribute value as a plain python object (str, int, float, bool, list)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", errors="replace")
    if isinstance(value, np.ndarray):
        return [py(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    return value


def column_names(signal: str, axes: tuple[str, ...] | None) -> list[str]:
    """DataFrame column names of a signal: ``<signal>_<axis>`` per axis, or ``<signal>``."""
    return [signal] if axes is None else [f"{signal}_{axis}" for axis in axes]


@dataclass(frozen=True)
class Layout:
    """What a scan learnt about an open store: log length, complete iterations and their groups, and
    its task dimension (n task axes and joints: its datasets are (n_log, n))."""

    n_log: int
    complete: tuple[int, ...]
    groups: dict[int, str]
    major: int
    dimension: int = schema.DEFAULT_TASK_DIMENSION


#: Largest store a reader copies into memory under its shared lock and then reads without the lock,
#: bytes, while a writer is at work on it (a finished store is read in place, lazily: a report reads
#: hundreds of them, a few datasets each). A reader that held the lock while it read (``ilcforce.open`` validates every byte: 150 ms
#: for a 40-iteration store) made a writer that commits every 35 ms wait for it at each commit, or
#: copy the file after a second: a reader polling a live store slowed its writer 6x (1.4 s -> 8.1 s,
#: measured). Copying the file takes 14 ms for 20 MB. A larger store is read under the lock.
SNAPSHOT_BYTES = 256 << 20


@contextmanager
def open_store(path: str | os.PathLike[str]) -> Iterator[tuple[h5py.File, Path, int]]:
    """Open a store read-only in bounded time, check its header; every h5py failure -> StoreError.

    Yields (file, path, schema major version). The file is read under its shared lock (a reader never
    sees half a commit): a store a writer is at work on, up to :data:`SNAPSHOT_BYTES`, is copied
    into memory under the lock and read from there after it; any other is read with the lock held.
    """
    path = Path(path)
    image = None
    with read_locked(path) as fd:
        version = superblock_version(fd)
        if version is None:
            raise StoreError(f"{path}: not a readable HDF5 file (no HDF5 signature)")
        info = os.fstat(fd)
        if info.st_size > SNAPSHOT_BYTES or not writer_active(path):
            probe(path, fd)  # bounded time even on a damaged file (safeio.probe)
            with _opened(path, None) as opened:
                yield opened
            return
        image = _read_image(fd, info.st_size, path)
        key = (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)
    probe(path, None, image=image, key=key)
    with _opened(path, image) as opened:
        yield opened


def _read_image(fd: int, size: int, path: Path) -> bytes:
    parts, done = [], 0
    while done < size:
        chunk = os.pread(fd, min(size - done, 64 << 20), done)
        if not chunk:
            break
        parts.append(chunk)
        done += len(chunk)
    if done != size:
        raise StoreError(f"{path}: the file shrank while it was read")
    return b"".join(parts)


@contextmanager
def _opened(path: Path, image: bytes | None) -> Iterator[tuple[h5py.File, Path, int]]:
    handle = None
    for attempt in range(3):
        try:
            handle = h5py.File(h5py.h5f.open_file_image(image)) if image is not None else h5py.File(path, "r")
            break
        except _H5_ERRORS as error:
            if "unable to lock file" in str(error) and attempt < 2:
                sleep(0.05)
                continue
            raise StoreError(f"{path}: not a readable HDF5 file ({one_line(error)})") from None
    try:
        with handle:
            major = check_header(handle, path)
            yield handle, path, major
    except StoreError:
        raise
    except _H5_ERRORS as error:
        raise StoreError(f"{path}: corrupt or unreadable store ({type(error).__name__}: {one_line(error)})") from None


def attr(obj: h5py.HLObject, name: str, kind: str, path: Path) -> Any:
    """Attribute ``name`` of ``obj`` checked to be of ``kind``; StoreError otherwise."""
    if name not in obj.attrs:
        raise StoreError(f"{path}: {obj.name} is missing attribute {name!r}")
    value = obj.attrs[name]
    if not schema.kind_matches(value, kind):
        raise StoreError(f"{path}: attribute {name!r} of {obj.name} is {value!r}, expected a {kind}")
    value = py(value)
    if kind == "float":
        return float(value)
    if kind == "bool":
        return bool(value)
    return value


def check_header(handle: h5py.File, path: Path) -> int:
    """Schema name and version, root attributes present with their kinds; returns the major."""
    if "schema" not in handle.attrs:
        raise StoreError(f"{path}: not an ilcforce store (HDF5 file without a 'schema' attribute)")
    name = py(handle.attrs["schema"])
    if name == schema.STUDY_SCHEMA_NAME:
        raise StoreError(f"{path}: {IS_A_STUDY_STORE}")
    if name != schema.SCHEMA_NAME:
        raise StoreError(f"{path}: not an ilcforce store (schema {name!r}, expected {schema.SCHEMA_NAME!r})")
    version = py(handle.attrs.get("schema_version", ""))
    try:
        major, _minor = schema.parse_version(version)
    except ValueError:
        raise StoreError(f"{path}: unreadable schema_version {version!r} (expected 'major.minor')") from None
    if major > schema.parse_version(schema.SCHEMA_VERSION)[0]:
        raise StoreError(f"{path}: written by a newer ilcforce (schema {version}); upgrade to read it "
                         f"(this ilcforce reads schema {schema.SCHEMA_VERSION})")
    missing = [n for n, spec in schema.ROOT_ATTRIBUTES.items() if spec.required and n not in handle.attrs]
    if missing:
        raise StoreError(f"{path}: store is missing root attributes {', '.join(missing)}")
    for key, spec in schema.ROOT_ATTRIBUTES.items():
        if key in handle.attrs:
            attr(handle, key, spec.kind, path)
    run_state = py(handle.attrs["run_state"])
    if run_state not in schema.RUN_STATES:
        raise StoreError(f"{path}: unknown run_state {run_state!r} (expected one of {', '.join(schema.RUN_STATES)})")
    for key, plain in (("method", schema.METHOD_NAME.fullmatch), ("experiment", schema.is_plain_name)):
        value = str(py(handle.attrs[key]))  # each names a results file or folder: never a path
        if not plain(value):
            raise StoreError(f"{path}: root attribute {key} {value[:60]!r} is not a plain name")
    for key in ("seed", "n_iterations_requested"):
        if int(py(handle.attrs[key])) < 0:
            raise StoreError(f"{path}: root attribute {key} is {int(py(handle.attrs[key]))}, below 0")
    state = attrs_state(handle)
    if state == "damaged":
        raise StoreError(f"{path}: the root attributes (configuration, command, provenance) do not match their "
                         f"checksum {ATTRS_SEAL}: changed or damaged after they were written")
    if state == "unsealed" and is_sealed_schema(version):
        raise StoreError(f"{path}: the root attributes carry no checksum ({ATTRS_SEAL}), which schema {version} requires")
    return major


def is_sealed_schema(version: str) -> bool:
    """Whether a store of schema ``version`` seals every object's attributes (:mod:`.seal`)."""
    try:
        return schema.parse_version(version) >= schema.SEALED_FROM
    except ValueError:
        return True


def is_bound_schema(version: str) -> bool:
    """Whether a store of schema ``version`` binds its records to itself (:mod:`.binding`)."""
    try:
        return schema.parse_version(version) >= schema.BOUND_FROM
    except ValueError:
        return True


def require_group(parent: h5py.Group, name: str, path: Path) -> h5py.Group:
    item = parent.get(name)
    if not isinstance(item, h5py.Group):
        where = f"{parent.name.rstrip('/')}/{name}"
        raise StoreError(f"{path}: missing group {where}" if item is None else f"{path}: {where} is not a group")
    return item


def require_dataset(group: h5py.Group, name: str, shape: tuple[int, ...] | None, path: Path,
                    kind: str = "f") -> h5py.Dataset:
    """Dataset ``name`` of ``group`` with dtype kind ``kind`` (numpy kind letters) and ``shape``."""
    item = group.get(name)
    where = f"{group.name.rstrip('/')}/{name}"
    if not isinstance(item, h5py.Dataset):
        raise StoreError(f"{path}: missing dataset {where}")
    if item.dtype.kind not in kind or (kind == "f" and item.dtype.itemsize != 8):
        raise StoreError(f"{path}: dataset {where} has type {item.dtype}, expected "
                         + {"f": "float64", "iu": "an integer", "OSU": "a string"}.get(kind, kind))
    if shape is not None and item.shape != shape:
        raise StoreError(f"{path}: dataset {where} has shape {item.shape}, expected {shape}")
    return item


def is_complete(group: h5py.Group) -> bool:
    flag = group.attrs.get("complete", False)
    return schema.kind_matches(flag, "bool") and bool(py(flag))


def task_dimension(handle: h5py.File, reference: h5py.Group, n_log: int, path: Path) -> int:
    """The store's task dimension n: its root attribute :data:`~ilcforce.store.schema.TASK_DIMENSION_ATTR`
    (absent: 2), checked to be a known dimension and the width of ``/reference/force_desired``
    (a shape, no data read); StoreError (one line) otherwise."""
    value = handle.attrs.get(schema.TASK_DIMENSION_ATTR)
    if value is None:
        dimension, said = schema.DEFAULT_TASK_DIMENSION, f"no root attribute {schema.TASK_DIMENSION_ATTR} (2 axes)"
    elif not schema.known_dimension(value):
        shown = str(py(value))[:40]
        raise StoreError(f"{path}: root attribute {schema.TASK_DIMENSION_ATTR} is {shown!r}, expected 2 or 3 "
                         "(the number of task axes)")
    else:
        dimension = int(py(value))
        said = f"root attribute {schema.TASK_DIMENSION_ATTR} = {dimension}"
    force = require_dataset(reference, "force_desired", None, path)
    if force.shape != (n_log, dimension):
        raise StoreError(f"{path}: {said} but /reference/force_desired has shape {force.shape}, expected "
                         f"{(n_log, dimension)}: the store's dimension does not match its data")
    return dimension


def scan(handle: h5py.File, path: Path, major: int) -> Layout:
    """Log length, task dimension and complete iterations (attributes and shapes only): what every
    reader needs."""
    reference = require_group(handle, "reference", path)
    time = require_dataset(reference, "time", None, path)
    if time.ndim != 1 or time.shape[0] < 2:
        raise StoreError(f"{path}: dataset /reference/time has shape {time.shape}, expected (n_log,) with n_log >= 2")
    dimension = task_dimension(handle, reference, int(time.shape[0]), path)
    iterations = require_group(handle, "iterations", path)
    complete: dict[int, str] = {}
    for name in iterations:
        if not isinstance(iterations.get(name, getlink=True), h5py.HardLink):
            raise StoreError(f"{path}: /iterations/{name[:40]} is a link, not an iteration of this store (a store "
                             "holds its own data only)")
        group = iterations.get(name)
        if not isinstance(group, h5py.Group) or not is_complete(group):
            continue  # an unfinished group (older stores): ignored
        if not (name.isascii() and name.isdigit()):
            raise StoreError(f"{path}: unexpected iteration group /iterations/{name}")
        complete[int(name)] = group.name
    ordered = tuple(sorted(complete))
    return Layout(int(time.shape[0]), ordered, {j: complete[j] for j in ordered}, major, dimension)


def group_for(layout: Layout, j: int, path: Path) -> str:
    if j not in layout.groups:
        stored = f"{layout.complete[0]}..{layout.complete[-1]}" if layout.complete else "none"
        raise StoreError(f"{path}: iteration {j} is not stored (complete iterations: {stored})")
    return layout.groups[j]


def iteration_attrs(group: h5py.Group, j: int, path: Path) -> dict[str, Any]:
    """The checked attributes of a complete iteration group."""
    out = {key: attr(group, key, spec.kind, path) for key, spec in schema.ITERATION_ATTRIBUTES.items()}
    if out["iteration"] != j:
        raise StoreError(f"{path}: {group.name} has attribute iteration={out['iteration']}")
    if out["status"] not in schema.ITERATION_STATUSES:
        raise StoreError(f"{path}: {group.name} has unknown status {out['status']!r}")
    if out["fallback_count"] < 0:
        raise StoreError(f"{path}: {group.name} has fallback_count {out['fallback_count']} < 0")
    return out


def read_log(group: h5py.Group, n_log: int, path: Path, major: int,
             dimension: int = schema.DEFAULT_TASK_DIMENSION) -> dict[str, np.ndarray]:
    """Every log signal of an iteration group of a store of ``dimension`` task axes, type-, shape-
    and (schema >= 2) checksum-checked."""
    log = require_group(group, "log", path)
    out = {}
    for name, (axes, _unit, _description) in schema.log_datasets(dimension).items():
        out[name] = checked_data(group, f"log/{name}",
                                 require_dataset(log, name, schema.signal_shape(axes, n_log), path), path, major)
    return out


def checked_data(group: h5py.Group, relative: str, dataset: h5py.Dataset, path: Path, major: int) -> np.ndarray:
    """The data of ``dataset`` (``group/relative``), its checksum verified for schema >= 2."""
    data = dataset[()]
    if major >= 2:
        verify(group, relative, data, path)
    return data


def read_memory_group(group: h5py.Group, path: Path, n_control: int | None) -> dict[str, h5py.Dataset]:
    """The memory datasets of an iteration group, type- and shape-checked."""
    memory = require_group(group, "memory", path)
    out = {}
    for name in memory:
        dataset = require_dataset(memory, name, None, path)
        if dataset.ndim not in (1, 2) or (n_control is not None and dataset.shape[0] != n_control):
            expected = "(n_control,) or (n_control, width)" if n_control is None else f"({n_control}, ...)"
            raise StoreError(f"{path}: dataset {dataset.name} has shape {dataset.shape}, expected {expected}")
        out[name] = dataset
    return out


def control_length(handle: h5py.File, path: Path) -> int | None:
    """n_control from /control_time (schema 2); None for older stores."""
    if schema.CONTROL_TIME not in handle:
        return None
    return int(require_dataset(handle, schema.CONTROL_TIME, None, path).shape[0])


def record_from_group(group: h5py.Group, j: int, n_log: int, path: Path, major: int,
                      log: dict[str, np.ndarray] | None = None,
                      dimension: int = schema.DEFAULT_TASK_DIMENSION) -> IterationRecord:
    """An :class:`IterationRecord` (without memory) rebuilt from a stored iteration (``log``: its
    :func:`read_log`, if the caller has read it already) of a store of ``dimension`` task axes."""
    a = iteration_attrs(group, j, path)
    return IterationRecord(iteration=j, status=a["status"], diverged_time=a["diverged_time"],
                           diverged_reason=a["diverged_reason"], fallback_count=a["fallback_count"],
                           log=read_log(group, n_log, path, major, dimension) if log is None else log)


def cached_metrics(handle: h5py.File, path: Path,
                   dimension: int = schema.DEFAULT_TASK_DIMENSION) -> dict[str, np.ndarray] | None:
    """The /metrics columns (:func:`ilcforce.metrics.metric_columns` of the store's ``dimension``) if
    the cache is current (same version, every column); else None."""
    metrics = handle.get(schema.METRICS_GROUP)
    if not isinstance(metrics, h5py.Group):
        return None
    version = metrics.attrs.get("metrics_version")
    if version is None or not schema.kind_matches(version, "int") or int(version) != METRICS_VERSION:
        return None
    columns: dict[str, np.ndarray] = {}
    for column in metric_columns(dimension):
        dataset = metrics.get(column)
        if not isinstance(dataset, h5py.Dataset) or dataset.ndim != 1:
            return None
        kind = column_kind(column)
        expected = {"int": "iu", "str": "OSU", "float": "f"}[kind]
        if dataset.dtype.kind not in expected:
            return None
        values = np.asarray(dataset.asstr()[()], dtype=object) if kind == "str" else dataset[()]
        columns[column] = values
    if len({v.shape for v in columns.values()}) > 1:
        raise StoreError(f"{path}: /metrics columns have different lengths")
    return columns


def metrics_rows(handle: h5py.File, path: Path, layout: Layout) -> dict[int, dict[str, object]]:
    """One metrics row per complete iteration: from the cache when current, else from the logs."""
    columns = cached_metrics(handle, path, layout.dimension)
    rows: dict[int, dict[str, object]] = {}
    if columns is not None:
        for k, j in enumerate(columns["iteration"]):
            rows[int(j)] = {column: values[k] for column, values in columns.items()}
    out = {}
    for j in layout.complete:
        if j in rows:
            out[j] = rows[j]
        else:  # stale or missing cache: the one definition, applied to the stored logs
            record = record_from_group(handle[layout.groups[j]], j, layout.n_log, path, layout.major,
                                       dimension=layout.dimension)
            out[j] = iteration_metrics(record)
    return out


def frame_from_group(group: h5py.Group, signals: Mapping[str, tuple[tuple[str, ...] | None, str, str]],
                     time: np.ndarray, n: int, path: Path, checksums: tuple[h5py.Group, str, int] | None = None
                     ) -> pd.DataFrame:
    """DataFrame indexed by ``time`` with one column per signal axis; ``attrs["units"]``."""
    data: dict[str, np.ndarray] = {}
    units: dict[str, str] = {"time": "s"}
    for signal, (axes, unit, _description) in signals.items():
        if signal == "time":
            continue
        dataset = require_dataset(group, signal, schema.signal_shape(axes, n), path)
        if checksums is not None:
            owner, prefix, major = checksums
            values = checked_data(owner, f"{prefix}{signal}", dataset, path, major)
        else:
            values = dataset[()]
        stored_unit = dataset.attrs.get("units", unit)
        names = column_names(signal, axes)
        if axes is None:
            data[names[0]] = values
        else:
            for column, name in enumerate(names):
                data[name] = values[:, column]
        for name in names:
            units[name] = str(py(stored_unit))
    import pandas as pd

    frame = pd.DataFrame(data, index=pd.Index(time, name="time"))
    frame.attrs["units"] = units
    return frame


def provenance_of(handle: h5py.File, path: Path) -> dict[str, Any]:
    names = list(schema.ROOT_ATTRS) + sorted(set(handle.attrs) - set(schema.ROOT_ATTRS))
    out = {name: py(handle.attrs[name]) for name in names if name in handle.attrs}
    if out.get("run_state") == "running" and not writer_active(path):
        out["run_state"] = "partial"  # the writer was killed (kill -9, power loss) mid-run
    return out
