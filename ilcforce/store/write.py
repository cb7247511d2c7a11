"""StoreWriter: one run into one store, one atomic commit per iteration (see :mod:`.commit`).

This module writes: the root attributes, the reference, each iteration's group and the /metrics
cache. What the writer checks at the path before its first commit (directory, leftovers,
--overwrite and --resume) is :mod:`.prepare`.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from types import TracebackType

import h5py
import numpy as np

import ilcforce
from ilcforce import stops
from ilcforce.metrics import iteration_metrics
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord, signals_dimension
from ilcforce.store import binding, commit, metrics_cache, schema
from ilcforce.store.provenance import SameRunCheck, git_state, text, utc_now
from ilcforce.store.prepare import (check_replaceable, check_resumable, clean_leftovers, existing_refusal, make_parent,
                                    refuse_foreign_target)
from ilcforce.store.seal import seal_attrs
from ilcforce.store.template import IterationTemplate
from ilcforce.store.safeio import (StoreError, StoreExistsError, StoreLockedError, acquire_writer_lock,
                                  check_writer_lock, one_line)


def _signal_array(arrays: Mapping[str, np.ndarray], argument: str, name: str,
                  axes: tuple[str, ...] | None, n: int) -> np.ndarray:
    if name not in arrays:
        raise ValueError(f"{argument} is missing signal {name!r}")
    array = np.ascontiguousarray(arrays[name], dtype=np.float64)
    if array.shape != schema.signal_shape(axes, n):
        raise ValueError(f"{argument}[{name!r}] has shape {array.shape}, expected {schema.signal_shape(axes, n)}")
    return array


def _dataset(group: h5py.Group, name: str, data: np.ndarray, units: str, description: str,
             axes: tuple[str, ...] | None = None, columns_attr: str = "axes") -> None:
    dataset = group.create_dataset(name, data=data, chunks=data.shape, **schema.DATASET_OPTIONS)
    attrs = dataset.attrs
    attrs["units"] = units
    attrs["description"] = description
    if axes is not None:
        attrs[columns_attr] = list(axes)
    seal_attrs(dataset)


def reference_dimension(reference: Mapping[str, np.ndarray]) -> int:
    """The task dimension n of a run from its reference: the width of ``force_desired`` (n_log, n)."""
    return signals_dimension(reference, "force_desired", "reference")


class StoreWriter:
    """Writes one run into ``results/<experiment>/<method>.h5``, one atomic commit per iteration.

    Use as a context manager::

        with StoreWriter(path, experiment=..., method=..., config_toml=..., config_json=...,
                         seed=..., command=..., n_iterations=..., reference=...) as writer:
            memory = writer.resume_memory()            # {} on a fresh run
            for j in range(writer.last_complete_iteration + 1, n_iterations):
                writer.append(simulate_iteration(j, memory))
            writer.finish("complete")

    Leaving the block without :meth:`finish` (exception, Ctrl-C) sets run_state ``"partial"``.
    ``same_run`` checks a stored run before ``resume`` continues it (default: the configuration
    must be equal except ``experiment.iterations``). ``control_time`` is the control grid
    (stored as ``/control_time``). ``overwrite`` replaces only an ilcforce store; anything else
    at ``path`` is refused. Raises StoreLockedError / StoreExistsError / StoreError on enter.
    """

    def __init__(self, path: str | os.PathLike[str], *, experiment: str, method: str, config_toml: str,
                 config_json: str, seed: int, command: str, n_iterations: int,
                 reference: dict[str, np.ndarray], control_time: np.ndarray | None = None,
                 overwrite: bool = False, resume: bool = False, same_run: SameRunCheck | None = None) -> None:
        self._path = Path(path)
        if self._path.name in ("", "..") or str(path) == "":
            raise StoreError(f"{str(path) or '(empty)'}: not a file name for a store (e.g. results/mine/c3.h5)")
        if overwrite and resume:
            raise StoreError(f"{self._path}: --overwrite and --resume are mutually exclusive; choose one")
        if int(n_iterations) != n_iterations or n_iterations < 0:
            raise ValueError(f"n_iterations must be an int >= 0, got {n_iterations!r}")
        self._experiment, self._method = text(experiment), text(method)
        self._config_toml, self._config_json = text(config_toml), text(config_json)
        self._seed, self._command, self._n_iterations = int(seed), text(command), int(n_iterations)
        self._overwrite, self._resume = bool(overwrite), bool(resume)
        self._same_run = same_run or _same_run_policy(self._config_json, method)
        if "time" not in reference or np.ndim(reference["time"]) != 1 or np.shape(reference["time"])[0] < 2:
            raise ValueError("reference['time'] must have shape (n_log,) with n_log >= 2")
        self._n_log = int(np.shape(reference["time"])[0])
        self._dimension = reference_dimension(reference)
        self._reference_signals = schema.reference_datasets(self._dimension)
        self._log_signals = schema.log_datasets(self._dimension)
        unknown = sorted(set(reference) - set(self._reference_signals))
        if unknown:
            raise ValueError(f"reference has unknown signal {unknown[0]!r} (not in records.REFERENCE_SIGNALS)")
        self._reference = {name: _signal_array(reference, "reference", name, axes, self._n_log).copy()
                           for name, (axes, _u, _d) in self._reference_signals.items()}
        self._control_time = None if control_time is None else np.ascontiguousarray(control_time, dtype=np.float64)
        self._lock_fd: int | None = None
        self._entered = self._finished = self._file_is_ours = self._appended = False
        self._last = -1
        self._last_status: str | None = None
        self._stored_run_state: str | None = None
        self._created_utc = utc_now()
        self._git = ("", False)
        self._template: IterationTemplate | None = None
        self._rows: list[dict[str, object]] = []
        self._store_id: str | None = None  # the store's identity (None: a store of schema 2.1 or older, resumed)
        self._key = b""

    # -- public ---------------------------------------------------------------------------

    @property
    def path(self) -> Path:
        return self._path

    @property
    def last_complete_iteration(self) -> int:
        """Last committed (or, on resume, stored) complete iteration; -1 if none."""
        return self._last

    def resume_memory(self) -> dict[str, np.ndarray]:
        """Memory stored with the last complete iteration; ``{}`` if none."""
        self._require_open()
        if self._last < 0 or not self._file_is_ours:
            return {}
        from ilcforce.store.access import read_memory
        return read_memory(self._path, self._last)

    def stored_status(self) -> str | None:
        """Status of the last complete iteration; None if none."""
        return self._last_status

    # -- context --------------------------------------------------------------------------

    def __enter__(self) -> StoreWriter:
        if self._entered:
            raise RuntimeError("a StoreWriter can be entered only once")
        make_parent(self._path)
        refuse_foreign_target(self._path)  # before the lock file: a refused target leaves nothing beside it
        self._lock_fd = acquire_writer_lock(self._path)
        try:
            clean_leftovers(self._path)
            self._git = git_state()
            if os.path.lexists(self._path):
                if self._resume:
                    self._load_for_resume()
                elif self._overwrite:
                    check_replaceable(self._path)
                else:
                    raise StoreExistsError(existing_refusal(self._path))
        except BaseException:
            self._release_lock()
            raise
        self._entered = True
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        try:
            if (not self._finished and self._file_is_ours and self._last >= 0
                    and (self._appended or self._stored_run_state == "running")):
                now = utc_now()

                def change(handle: h5py.File) -> None:
                    metrics_cache.append_rows(handle, self._rows)
                    self._set_run_state(handle, "partial", now)

                try:
                    with stops.critical():
                        commit.update(self._path, change)
                        self._rows = []
                except Exception:
                    if exc_type is None:
                        raise
        finally:
            if self._template is not None:
                self._template.close()
                self._template = None
            self._release_lock()
            self._entered = False

    # -- writing --------------------------------------------------------------------------

    @property
    def finished(self) -> bool:
        """True once the run is marked finished (:meth:`finish`, or ``append(..., finish=...)``)."""
        return self._finished

    def append(self, record: IterationRecord, finish: str | None = None) -> dict[str, object]:
        """Commit one iteration atomically; returns its metrics row. ``record.iteration`` must be the next one.

        ``finish`` ("complete" or "diverged"): this is the run's last iteration, and the same commit
        marks the run finished, as :meth:`finish` would after it (one commit instead of two).
        """
        self._require_open()
        if finish is not None and finish not in (STATUS_COMPLETE, STATUS_DIVERGED):
            raise ValueError(f"finish must be {STATUS_COMPLETE!r} or {STATUS_DIVERGED!r}, got {finish!r}")
        if self._finished:
            raise StoreError(f"{self._path}: run already finished; cannot append iteration {record.iteration}")
        if record.iteration != self._last + 1:
            raise StoreError(f"{self._path}: cannot append iteration {record.iteration}: the last complete "
                             f"iteration is {self._last}, so the next must be {self._last + 1}")
        log, memory, row = self._check_record(record)
        first_of_session = not self._appended
        now = utc_now()

        template = self._template_for(record, memory)
        row = dict(row)

        def write(handle: h5py.File) -> None:
            name = f"iterations/{record.iteration:04d}"
            if name in handle:  # an unfinished group left by hand or an old version: replace it
                del handle[name]
            group = template.stamp(handle, f"iterations/{record.iteration:04d}", log, memory)
            attrs = group.attrs
            stored = (str(record.status), float(record.diverged_time), text(one_line(record.diverged_reason)),
                      int(record.fallback_count))
            attrs["iteration"] = int(record.iteration)
            attrs["status"], attrs["diverged_time"], attrs["diverged_reason"], attrs["fallback_count"] = stored
            if self._store_id is not None:  # bound to this store and this place (ilcforce.store.binding)
                shapes = [log[s].shape for s in template.signals] + [memory[m[0]].shape for m in template.memory]
                attrs[binding.BINDING] = binding.iteration_binding(
                    self._key, record.iteration, *stored, zip(template.names, shapes, template.sums))
                handle.attrs[binding.STORED] = int(record.iteration) + 1
            if first_of_session:
                self._write_invocation_attrs(handle)
            if finish is None:
                self._set_run_state(handle, "running", now)
            else:
                metrics_cache.append_rows(handle, [*self._rows, row])
                self._set_run_state(handle, finish, now)
            attrs["complete"] = True
            seal_attrs(group)

        def build(handle: h5py.File) -> None:
            self._initialise(handle)
            write(handle)

        with stops.critical():  # a stop signal waits for the commit and this writer's account of it
            if self._file_is_ours:
                commit.update(self._path, write)
            else:
                commit.create(self._path, build)
                self._file_is_ours = True
            self._appended = True
            self._last = int(record.iteration)
            self._last_status = str(record.status)
            if finish is None:
                self._rows.append(row)
            else:
                self._rows = []
                self._finished = True
        return row

    def _template_for(self, record: IterationRecord, memory: dict[str, np.ndarray]) -> IterationTemplate:
        labels = getattr(record, "memory_labels", None) or {}
        spec = tuple((key, values.shape, str(record.memory_units[key]),
                      tuple(str(c) for c in labels[key]) if values.ndim == 2 and labels.get(key) else None)
                     for key, values in memory.items())
        if self._template is None or self._template.memory != spec or self._template.n_log != self._n_log:
            if self._template is not None:
                self._template.close()
            self._template = IterationTemplate(self._n_log, spec, self._dimension)
        return self._template

    def finish(self, status: str) -> None:
        """Mark the run ``"complete"`` or ``"diverged"`` (committed atomically)."""
        self._require_open()
        if status not in (STATUS_COMPLETE, STATUS_DIVERGED):
            raise ValueError(f"status must be {STATUS_COMPLETE!r} or {STATUS_DIVERGED!r}, got {status!r}")
        if not self._file_is_ours or self._last < 0:
            raise StoreError(f"{self._path}: cannot finish a run with no stored iteration")
        now = utc_now()

        def change(handle: h5py.File) -> None:
            metrics_cache.append_rows(handle, self._rows)
            self._set_run_state(handle, status, now)

        with stops.critical():
            commit.update(self._path, change)
            self._rows = []
            self._finished = True

    # -- internals ------------------------------------------------------------------------

    def _require_open(self) -> None:
        if not self._entered:
            raise RuntimeError("StoreWriter must be used as a context manager ('with StoreWriter(...) as writer')")
        if self._lock_fd is not None and not check_writer_lock(self._lock_fd):
            raise StoreLockedError(f"{self._path}: its lock file was deleted or replaced while this run held it, so "
                                   "another writer may be in; stopping before the next commit (every finished "
                                   "iteration is kept)")

    def _release_lock(self) -> None:
        if self._lock_fd is not None:
            os.close(self._lock_fd)  # closing releases the flock
            self._lock_fd = None

    def _load_for_resume(self) -> None:
        from ilcforce.store.access import iterations
        provenance = check_resumable(self._path, experiment=self._experiment, method=self._method,
                                     seed=self._seed, same_run=self._same_run, reference=self._reference)
        done = iterations(self._path)
        self._file_is_ours = True
        self._stored_run_state = str(provenance["run_state"])
        if provenance.get(binding.STORE_ID) is not None:  # a store of schema 2.1 or older stays unbound
            if (binding.config_digest(str(provenance["config_json"]), self._method)
                    != binding.config_digest(self._config_json, self._method)):
                raise StoreError(f"{self._path}: cannot resume: the configuration differs from the stored one in "
                                 "what the results depend on; use --overwrite to start again")
            self._bind(str(provenance[binding.STORE_ID]))
        if done:
            from ilcforce.store.access import read_iteration, read_metrics_rows
            self._last = done[-1]
            self._last_status = str(read_iteration(self._path, self._last).attrs["status"])
            # a run killed before its last commit left no /metrics rows for that session's iterations
            # (they are written at a run's end): the rows the cache lacks, recomputed from the stored
            # logs, go in with this session's (append_rows skips the ones it holds)
            self._rows = [row for _, row in sorted(read_metrics_rows(self._path).items())]

    def _check_record(self, record: IterationRecord) -> tuple[dict, dict, dict]:
        if record.status not in (STATUS_COMPLETE, STATUS_DIVERGED):
            raise ValueError(f"record.status must be {STATUS_COMPLETE!r} or {STATUS_DIVERGED!r}, got {record.status!r}")
        unknown = sorted(set(record.log) - set(self._log_signals))
        if unknown:
            raise ValueError(f"record.log has unknown signal {unknown[0]!r} (not in records.LOG_SIGNALS)")
        log = {name: _signal_array(record.log, "record.log", name, axes, self._n_log)
               for name, (axes, _u, _d) in self._log_signals.items()}
        memory: dict[str, np.ndarray] = {}
        for key, values in record.memory.items():
            if not key or "/" in key or key == "." or not key.isprintable():
                raise ValueError(f"record.memory key {key!r} is not a valid dataset name")
            if key not in record.memory_units:
                raise ValueError(f"record.memory_units has no unit for memory {key!r}")
            array = np.ascontiguousarray(values, dtype=np.float64)
            if array.ndim not in (1, 2):
                raise ValueError(f"record.memory[{key!r}] must be (n_control,) or (n_control, width), got {array.shape}")
            if self._control_time is not None and array.shape[0] != self._control_time.shape[0]:
                raise ValueError(f"record.memory[{key!r}] has {array.shape[0]} samples, the control grid "
                                 f"{self._control_time.shape[0]}")
            memory[key] = array
        return log, memory, iteration_metrics(record)

    def _bind(self, store_id: str) -> None:
        self._store_id = store_id
        self._key = binding.run_key(store_id, self._seed, self._experiment, self._method, self._config_json)

    def _initialise(self, handle: h5py.File) -> None:
        self._bind(binding.new_store_id())
        attrs = handle.attrs
        attrs["schema"] = schema.SCHEMA_NAME
        attrs["schema_version"] = schema.SCHEMA_VERSION
        attrs["ilcforce_version"] = str(ilcforce.__version__)
        attrs["git_commit"], attrs["git_dirty"] = self._git[0], bool(self._git[1])
        attrs["created_utc"] = attrs["updated_utc"] = self._created_utc
        attrs["experiment"] = self._experiment
        attrs["method"] = self._method
        attrs["seed"] = self._seed
        attrs["run_state"] = "running"
        attrs[binding.STORE_ID] = self._store_id
        attrs[binding.STORED] = 0
        self._write_invocation_attrs(handle)
        if self._dimension != schema.DEFAULT_TASK_DIMENSION:  # a 2-axis store stays as it was: no attribute
            attrs[schema.TASK_DIMENSION_ATTR] = self._dimension
        reference = handle.create_group("reference")
        for name, (axes, unit, description) in self._reference_signals.items():
            _dataset(reference, name, self._reference[name], unit, description, axes)
        if self._control_time is not None:
            _dataset(handle, schema.CONTROL_TIME, self._control_time, "s",
                     "control grid t_k = k Ts: the time axis of every learned memory")
        reference.attrs[binding.BINDING] = binding.data_binding(self._key, "/reference", binding.reference_arrays(
            self._reference, self._control_time))
        seal_attrs(reference)
        handle.create_group("iterations")
        metrics_cache.create(handle, self._dimension)

    def _write_invocation_attrs(self, handle: h5py.File) -> None:
        handle.attrs["command"] = self._command
        handle.attrs["config_toml"] = self._config_toml
        handle.attrs["config_json"] = self._config_json
        handle.attrs["n_iterations_requested"] = self._n_iterations

    @staticmethod
    def _set_run_state(handle: h5py.File, state: str, now: str) -> None:
        """Set the run state; the last change of the root attributes in every commit, so it seals them."""
        handle.attrs["run_state"] = state
        handle.attrs["updated_utc"] = now
        seal_attrs(handle)


def _same_run_policy(config_json: str, method: str) -> SameRunCheck:
    """The same-run policy (:mod:`ilcforce.samerun`) for a writer not given one."""
    import json

    from ilcforce import samerun

    try:
        config = json.loads(config_json)
    except json.JSONDecodeError:
        raise StoreError("the configuration to store is not valid JSON") from None
    return samerun.same_run_check(config if isinstance(config, dict) else {}, method)
