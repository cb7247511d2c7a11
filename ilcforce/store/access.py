"""The public readers: validate, provenance, metrics, iterations, memory, reference, find_stores."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import TYPE_CHECKING, Any

import h5py
import numpy as np

if TYPE_CHECKING:  # pandas only where a frame is built: writing a run imports none
    import pandas as pd

from ilcforce.metrics import METRICS_VERSION, column_kind, iteration_metrics, metric_columns
from ilcforce.store import binding, schema
from ilcforce.store.seal import ATTRS_SEAL, attrs_state
from ilcforce.store.filecheck import check_links
from ilcforce.store.read import (attr, cached_metrics, checked_data, control_length, frame_from_group, group_for,
                                 is_bound_schema, is_complete, is_sealed_schema, iteration_attrs, metrics_rows,
                                 open_store, provenance_of, py, read_log, read_memory_group, record_from_group,
                                 require_dataset, require_group, scan)
from ilcforce.store.safeio import StoreError


def validate(path: str | os.PathLike[str]) -> list[str]:
    """Check that ``path`` is a readable ilcforce store; raise StoreError (one line) if not.

    Returns notes on what could not be verified: ``["metadata unverified ..."]`` for a store of
    schema 2.0, written before attributes were sealed (:mod:`ilcforce.store.seal`): accepted, its
    data checksums verified, its attributes not (a sealed store's every seal is verified, and a
    sealed-schema store without one is refused).

    Reads every byte of every dataset (so every checksum is verified) and checks the kind of
    every attribute and the type and shape of every dataset a reader uses: the header
    (:data:`~ilcforce.store.schema.ROOT_ATTRIBUTES`), the task dimension (``task_dimension``,
    absent: 2) against the data, ``/reference``, every complete iteration (attributes, log,
    memory, units, every array (n_log, n) for the store's n), the bindings of every record to the
    store and its place (schema 2.2 on, :mod:`ilcforce.store.binding`; a 2.1 store gets the note
    ``"records not bound ..."``) and, when current, the ``/metrics`` cache (one row per complete
    iteration). A stale metrics cache is not an error: readers recompute it.
    """
    with open_store(path) as (handle, checked, major):
        check_links(handle, checked)
        layout = scan(handle, checked, major)
        dimension = layout.dimension
        reference = require_group(handle, "reference", checked)
        signals = {name: require_dataset(reference, name, schema.signal_shape(axes, layout.n_log), checked)[()]
                   for name, (axes, _unit, _description) in schema.reference_datasets(dimension).items()}
        n_control = control_length(handle, checked)
        control_time = handle[schema.CONTROL_TIME][()] if n_control is not None else None
        columns = cached_metrics(handle, checked, dimension)
        fresh_rows: dict[int, dict] = {}  # metrics of each complete iteration, from the log read once here
        statuses: dict[int, str] = {}
        shapes: dict[int, dict[str, tuple[int, ...]]] = {}  # per iteration, its datasets' shapes (the bindings)
        found: dict[int, dict[str, Any]] = {}  # per iteration, its checked attributes
        for j in layout.complete:
            group = handle[layout.groups[j]]
            found[j] = iteration_attrs(group, j, checked)
            statuses[j] = found[j]["status"]
            log = read_log(group, layout.n_log, checked, major, dimension)
            if columns is not None:
                fresh_rows[j] = iteration_metrics(record_from_group(group, j, layout.n_log, checked, major, log=log,
                                                                    dimension=dimension))
            shapes[j] = {f"log/{name}": values.shape for name, values in log.items()}
            for name, dataset in read_memory_group(group, checked, n_control).items():
                checked_data(group, f"memory/{name}", dataset, checked, major)
                shapes[j][f"memory/{name}"] = dataset.shape
        _check_units(handle, checked)
        _check_consistency(handle, statuses, checked)
        _check_method(handle, checked)
        unsealed = _check_seals(handle, checked)
        bound = _check_bindings(handle, layout, checked, binding.reference_arrays(signals, control_time), shapes,
                                found)
        version = py(handle.attrs["schema_version"])
        if columns is not None:  # a current cache must agree with the logs it was computed from
            for k, j in enumerate(columns["iteration"]):
                j = int(j)
                if j not in layout.groups:
                    continue
                fresh = fresh_rows.get(j)
                if fresh is None:  # a cached row of an iteration that is not complete
                    fresh = iteration_metrics(record_from_group(handle[layout.groups[j]], j, layout.n_log, checked,
                                                                major, dimension=dimension))
                for column, value in fresh.items():
                    cached = columns[column][k]
                    same = (str(cached) == str(value) if column_kind(column) == "str"
                            else np.array_equal(np.float64(cached), np.float64(value), equal_nan=True))
                    if not same:
                        raise StoreError(f"{checked}: /metrics/{column} of iteration {j} is {cached!r} but the stored "
                                         f"log gives {value!r}")
    if unsealed:
        return [f"metadata unverified: {unsealed} object(s) without an attribute checksum (schema 2.0, written "
                "before attributes were sealed)"]
    if not bound:
        return [f"records not bound to the store (schema {version}, written before "
                "records were bound: an iteration copied from another store is not detected)"]
    return []


def _check_bindings(handle: h5py.File, layout, path: Path, reference: list[tuple[str, np.ndarray]],
                    shapes: dict[int, dict[str, tuple[int, ...]]], found: dict[int, dict[str, Any]]) -> bool:
    """Every record of a store of schema 2.2 on is bound to the store and its place
    (:mod:`ilcforce.store.binding`): ``/reference`` and each complete iteration carry the binding their
    content, place and the store's key give, and the iterations are 0 .. n_iterations_stored - 1.
    ``shapes``: per complete iteration, the shape of each dataset validate read from it (``log/<name>``,
    ``memory/<name>``); ``found``: its checked attributes (:func:`iteration_attrs`). Returns whether the
    store is bound (False: an older store, which must carry no binding at all)."""
    version = str(py(handle.attrs["schema_version"]))
    groups = [handle["reference"], *(handle[layout.groups[j]] for j in layout.complete)]
    if not is_bound_schema(version):
        carried = [g.name for g in groups if binding.BINDING in g.attrs] + (
            ["/"] if binding.STORE_ID in handle.attrs or binding.STORED in handle.attrs else [])
        if carried:
            raise StoreError(f"{path}: {carried[0]} carries a binding or store identity, which its schema {version} "
                             "does not have: altered after it was written")
        return False
    for name in (binding.STORE_ID, binding.STORED):
        if name not in handle.attrs:
            raise StoreError(f"{path}: the root lacks attribute {name!r}, which schema {version} requires")
    store_id, stored = py(handle.attrs[binding.STORE_ID]), py(handle.attrs[binding.STORED])
    if layout.complete != tuple(range(int(stored))):
        shown = f"{layout.complete[0]}..{layout.complete[-1]}" if layout.complete else "none"
        raise StoreError(f"{path}: it holds iterations {shown} ({len(layout.complete)}) but says it stored "
                         f"0..{int(stored) - 1}: an iteration was removed or added after it was written")
    key = binding.run_key(store_id, py(handle.attrs["seed"]), py(handle.attrs["experiment"]),
                          py(handle.attrs["method"]), py(handle.attrs["config_json"]))
    if py(groups[0].attrs.get(binding.BINDING)) != binding.data_binding(key, "/reference", reference):
        raise StoreError(f"{path}: /reference is not bound to this store's identity, seed and configuration (its "
                         f"{binding.BINDING} does not match: the reference or control grid copied from another "
                         "store, or they or the root's store_id, seed or configuration changed after writing)")
    for j in layout.complete:
        group = handle[layout.groups[j]]
        names = [str(n) for n in py(group.attrs["crc32_datasets"])]
        held = {*shapes[j], *(f"log/{n}" for n in group["log"]),
                *(f"{n}/" for n in group if n not in ("log", "memory"))}
        if held != set(names):
            extra = sorted(held ^ set(names))
            raise StoreError(f"{path}: {group.name} holds other objects than its checksums list "
                             f"({', '.join(extra[:3])}): altered after it was written")
        a = found[j]
        expected = binding.iteration_binding(
            key, j, a["status"], a["diverged_time"], a["diverged_reason"], a["fallback_count"],
            zip(names, (shapes[j][n] for n in names), np.asarray(group.attrs["crc32"]).tolist()))
        stored_binding = py(group.attrs.get(binding.BINDING))
        if stored_binding != expected:
            why = (f"it has no {binding.BINDING}: copied from a store of an older schema, or altered"
                   if stored_binding is None else f"its {binding.BINDING} does not match: copied from another store "
                   "or iteration, or changed after it was written")
            raise StoreError(f"{path}: {group.name} is not bound to this store and place ({why})")
    return True


def _check_method(handle: h5py.File, path: Path) -> None:
    """The stored method is a registered one (the store's file name and its report labels come from it)."""
    from ilcforce.controllers import REGISTRY

    method = str(py(handle.attrs["method"]))
    if method not in REGISTRY:
        raise StoreError(f"{path}: method {method[:60]!r} is not a registered method ({', '.join(REGISTRY)})")


def _check_seals(handle: h5py.File, path: Path) -> int:
    """Verify the attribute checksum of every object a reader uses; the number of objects without
    one (allowed only below schema 2.1; an incomplete iteration group is not read, so not checked)."""
    sealed_schema = is_sealed_schema(str(py(handle.attrs["schema_version"])))
    unsealed = [0]
    problems: list[str] = []

    def check(name: str, item: Any) -> None:
        parts = name.split("/")
        if parts[0] == "iterations" and len(parts) > 1:
            group = handle.get(f"iterations/{parts[1]}")
            if not isinstance(group, h5py.Group) or not is_complete(group):
                return
        if not len(item.attrs):
            return
        state = attrs_state(item)
        if state == "damaged" or (state == "unsealed" and sealed_schema):
            problems.append(item.name)
        elif state == "unsealed":
            unsealed[0] += 1

    check("", handle)
    handle.visititems(check)
    if problems:
        raise StoreError(f"{path}: the attributes of {problems[0]} (units, labels, description or state) do not match "
                         f"their checksum {ATTRS_SEAL} or have none: damaged ({len(problems)} object(s))")
    return unsealed[0]


def _check_consistency(handle: h5py.File, statuses: dict[int, str], path: Path) -> None:
    """The header agrees with the iterations: ``config_json`` is a JSON object, nothing follows a
    diverged iteration, a "diverged" run ends with one, and a "complete" run holds every iteration
    its latest invocation asked for and none diverged."""
    try:
        config = json.loads(str(py(handle.attrs["config_json"])))
    except (ValueError, RecursionError):
        config = None
    if not isinstance(config, dict):
        raise StoreError(f"{path}: root attribute config_json is not a JSON object")
    order = sorted(statuses)
    diverged = [j for j in order if statuses[j] == "diverged"]
    if diverged and diverged[0] != order[-1]:
        raise StoreError(f"{path}: iteration {order[-1]} is stored after the diverged iteration {diverged[0]}")
    state = py(handle.attrs["run_state"])
    if state == "diverged" and not diverged:
        raise StoreError(f"{path}: run_state is 'diverged' but no stored iteration diverged")
    if state == "complete":
        if diverged:
            raise StoreError(f"{path}: run_state is 'complete' but iteration {diverged[0]} diverged")
        requested = int(py(handle.attrs["n_iterations_requested"]))
        if len(order) < requested:
            raise StoreError(f"{path}: run_state is 'complete' but it holds {len(order)} of the {requested} "
                             "iterations requested")


def _check_units(handle: h5py.File, path: Path) -> None:
    """Every dataset a reader uses has a string ``units`` attribute."""
    problems: list[str] = []

    def visit(name: str, item: Any) -> None:
        if isinstance(item, h5py.Dataset):
            parts = name.split("/")
            if parts[0] == "iterations" and len(parts) > 1:
                group = handle.get(f"iterations/{parts[1]}")
                if not isinstance(group, h5py.Group) or not is_complete(group):
                    return
            if not schema.kind_matches(item.attrs.get("units"), "str"):
                problems.append(item.name)

    handle.visititems(visit)
    if problems:
        raise StoreError(f"{path}: dataset {problems[0]} has no 'units' attribute ({len(problems)} without units)")


def iterations(path: str | os.PathLike[str]) -> list[int]:
    """Complete iterations stored in ``path``, ascending."""
    with open_store(path) as (handle, checked, major):
        return list(scan(handle, checked, major).complete)


def read_task_dimension(path: str | os.PathLike[str]) -> int:
    """The store's task dimension n (2 or 3): its task-space and joint-space arrays are (n_log, n)
    with the axes of :func:`ilcforce.records.task_axes` / ``joint_axes`` of n."""
    with open_store(path) as (handle, checked, major):
        return scan(handle, checked, major).dimension


def read_provenance(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Root attributes as python types (str, int, float, bool, list), :data:`ROOT_ATTRS` first.

    ``run_state`` "running" with no live writer reads as "partial" (the writer was killed).
    """
    with open_store(path) as (handle, checked, major):
        scan(handle, checked, major)
        return provenance_of(handle, checked)


def read_metrics(path: str | os.PathLike[str]) -> pd.DataFrame:
    """The metrics table of the complete iterations.

    Returns
    -------
    DataFrame
        Indexed by ``iteration`` (int), ascending; columns :func:`ilcforce.metrics.metric_columns`
        of the store's task dimension (:data:`ilcforce.metrics.METRIC_COLUMNS` for 2 axes) except
        ``iteration``, in that order (``status`` str, ``fallback_count`` int, the rest
        float). ``df.attrs["units"]`` maps column -> unit (``"1"`` dimensionless, ``""`` text),
        ``df.attrs["descriptions"]`` column -> description. Taken from the store's ``/metrics``
        cache when it is current, else computed from the stored logs.
    """
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        rows = metrics_rows(handle, checked, layout)
    return metrics_frame(rows, layout.dimension)


def read_metrics_rows(path: str | os.PathLike[str]) -> dict[int, dict[str, object]]:
    """The rows of :func:`read_metrics` without pandas: iteration -> {column: value} for the
    complete iterations (every column of :func:`ilcforce.metrics.metric_columns` of the store's
    task dimension)."""
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        return metrics_rows(handle, checked, layout)


def metrics_frame(rows: dict[int, dict[str, object]], dimension: int = schema.DEFAULT_TASK_DIMENSION
                  ) -> pd.DataFrame:
    """The metrics DataFrame of :func:`read_metrics` from rows keyed by iteration, of a task of
    ``dimension`` axes."""
    order = sorted(rows)
    data = {}
    table = metric_columns(dimension)
    for column in table:
        if column == "iteration":
            continue
        values = [rows[j][column] for j in order]
        kind = column_kind(column)
        dtype = {"int": np.int64, "str": object, "float": np.float64}[kind]
        data[column] = np.asarray([str(v) for v in values] if kind == "str" else values, dtype=dtype)
    import pandas as pd

    frame = pd.DataFrame(data, index=pd.Index(np.asarray(order, dtype=np.int64), name="iteration"))
    if "status" in frame:
        frame["status"] = frame["status"].astype(str)
    frame.attrs["units"] = {c: table[c][0] for c in frame.columns}
    frame.attrs["descriptions"] = {c: table[c][1] for c in frame.columns}
    frame.attrs["metrics_version"] = METRICS_VERSION
    return frame


def read_iteration(path: str | os.PathLike[str], j: int) -> pd.DataFrame:
    """The logged trajectories of iteration ``j``.

    Returns
    -------
    DataFrame, shape (n_log, 32)
        Index ``time`` (s): the iteration's logged time; samples after a divergence (NaN in the
        log) take the log-grid time from ``/reference/time`` so the index has no gaps. One
        column per signal axis of :func:`~ilcforce.records.log_signals` of the store's task
        dimension (:data:`~ilcforce.records.LOG_SIGNALS` for 2 axes; 3 axes: n_log x 44), named
        ``<signal>_<axis>`` (``position_x``, ``position_u``, ``torque_1``) or ``<signal>`` for a
        scalar signal.
        ``df.attrs``: ``units`` (column -> unit, including ``time``), ``iteration``,
        ``status``, ``fallback_count``, ``diverged_time`` (s), ``diverged_reason``.
    """
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        group = handle[group_for(layout, int(j), checked)]
        attrs = iteration_attrs(group, int(j), checked)
        log = require_group(group, "log", checked)
        time = checked_data(group, "log/time", require_dataset(log, "time", (layout.n_log,), checked), checked, major)
        reference_time = handle["reference/time"][()]
        time = np.where(np.isfinite(time), time, reference_time)
        frame = frame_from_group(log, schema.log_datasets(layout.dimension), time, layout.n_log, checked,
                                 (group, "log/", major))
    for key in ("iteration", "status", "fallback_count", "diverged_time", "diverged_reason"):
        frame.attrs[key] = attrs[key]
    return frame


def read_memory(path: str | os.PathLike[str], j: int) -> dict[str, np.ndarray]:
    """Learned memory stored with iteration ``j`` (the memory iteration j + 1 starts from).

    Returns name -> float64 array, shape (n_control, ...), exact copies; empty for a
    memoryless controller.
    """
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        group = handle[group_for(layout, int(j), checked)]
        datasets = read_memory_group(group, checked, control_length(handle, checked))
        return {name: np.array(checked_data(group, f"memory/{name}", d, checked, major), dtype=np.float64)
                for name, d in datasets.items()}


def read_memories(path: str | os.PathLike[str], iterations: list[int]) -> dict[int, dict[str, np.ndarray]]:
    """:func:`read_memory` of each of ``iterations``, with the file opened and scanned once.

    (A loop over :func:`read_memory` opens and scans the file per iteration: quadratic in the
    number of iterations, which made the long-run report slow.) Returns j -> name -> array.
    """
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        n_control = control_length(handle, checked)
        out = {}
        for j in iterations:
            group = handle[group_for(layout, int(j), checked)]
            datasets = read_memory_group(group, checked, n_control)
            out[int(j)] = {name: np.array(checked_data(group, f"memory/{name}", d, checked, major), dtype=np.float64)
                           for name, d in datasets.items()}
        return out


def read_memory_info(path: str | os.PathLike[str], j: int) -> dict[str, dict[str, Any]]:
    """Per memory entry of iteration ``j``: ``units`` and ``columns`` (labels, or None)."""
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        group = handle[group_for(layout, int(j), checked)]
        datasets = read_memory_group(group, checked, control_length(handle, checked))
        out = {}
        for name, dataset in datasets.items():
            columns = dataset.attrs.get("columns")
            out[name] = {"units": str(py(dataset.attrs.get("units", ""))),
                         "columns": [str(c) for c in py(columns)] if columns is not None else None}
        return out


def read_memory_units(path: str | os.PathLike[str], j: int) -> dict[str, str]:
    """Units of the learned memory stored with iteration ``j``: name -> unit."""
    return {name: info["units"] for name, info in read_memory_info(path, j).items()}


def read_reference(path: str | os.PathLike[str]) -> pd.DataFrame:
    """The reference trajectories: DataFrame indexed by ``time`` (s), columns
    ``<signal>_<axis>`` of :func:`~ilcforce.records.reference_signals` of the store's task
    dimension (e.g. ``position_desired_x``; ``position_desired_u`` for 3 axes), ``df.attrs["units"]``
    column -> unit. Shape (n_log, 8) for 2 axes, (n_log, 12) for 3."""
    with open_store(path) as (handle, checked, major):
        layout = scan(handle, checked, major)
        reference = require_group(handle, "reference", checked)
        return frame_from_group(reference, schema.reference_datasets(layout.dimension), reference["time"][()],
                                layout.n_log, checked)


def read_control_time(path: str | os.PathLike[str]) -> np.ndarray | None:
    """The control grid (s) of a schema-2 store; None for older stores."""
    with open_store(path) as (handle, checked, major):
        if control_length(handle, checked) is None:
            return None
        return np.array(handle[schema.CONTROL_TIME][()], dtype=np.float64)


def find_stores(results_dir: str | os.PathLike[str]) -> dict[str, dict[str, Path]]:
    """Every ``results_dir/<experiment>/<method>.h5``: experiment -> method -> path, sorted.

    Only regular files named ``*.h5`` count (lock files, journals, leftover copies and
    anything else are skipped). The files are not opened (use :func:`validate`). Names are
    compared literally, never as glob patterns. StoreError if ``results_dir`` is not a directory.
    """
    root = Path(results_dir)
    if not root.is_dir():
        raise StoreError(f"{root}: results directory does not exist or is not a directory")
    found: dict[str, dict[str, Path]] = {}
    for experiment_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        methods = {}
        for entry in sorted(experiment_dir.iterdir()):
            try:
                regular = stat.S_ISREG(entry.stat().st_mode)
            except OSError:
                continue
            if regular and entry.suffix == ".h5" and not entry.name.startswith("."):
                methods[entry.stem] = entry
        if methods:
            found[experiment_dir.name] = methods
    return found
