"""The study store's writer, ``results/studies/<name>.h5`` (readers: :mod:`.study_read`; layout,
schema ``ilcforce.study`` 1.3, and what protects each byte: docs/store-format.md).

Only the driver writes it, never an HDF5 file in place: a finished (or failed) cell is committed at
once as one sealed JSON record in the journal ``<name>.h5.journal/`` (:mod:`.records`, checked by
:mod:`.study_journal`); every few seconds, and at the end, the journal is **consolidated** into
``<name>.h5`` by copy, append, fsync and rename (:func:`.commit.replace`), so the file is always a
whole older or newer version. Readers take the file plus the journal records not yet in it. So
``kill -9`` of the driver loses only the cells in flight; a rerun skips every committed cell. The
writers' lock (:func:`~.safeio.acquire_writer_lock`) refuses a second driver on the same study.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import uuid
from pathlib import Path

import h5py
import numpy as np

from ilcforce import stops
from ilcforce.store import binding, commit, records, study_journal
from ilcforce.store.seal import DATA_SEAL, STRINGS_SEAL, data_digest, seal_attrs, strings_checksum
from ilcforce.store.filecheck import StoreError, writers_lock
from ilcforce.store.safeio import (acquire_writer_lock, check_writer_lock, dead_copies_in, dead_writers_copies, is_hdf5_file,
                                  one_line)
from ilcforce.store.study_read import (  # noqa: F401 - re-exported: the study layer reads through here
    CELL_COLUMNS, DONE, FAILED, KEY_COLUMNS, SCHEMA_NAME, SCHEMA_VERSION, StudyStoreError, _CHUNK, _STRING,
    _keys, _table, fold, is_study_store, journal_dir, read_header, read_tables, scan_journal,
    study_facts, study_key,
)


def _append(group: h5py.Group, rows: list[dict]) -> None:
    """Append ``rows`` (dicts) to the column datasets of ``group``; new columns are back-filled."""
    if not rows:
        return
    n_old = int(group.attrs.get("n_rows", 0))
    columns = json.loads(group.attrs.get("columns_json", "[]"))
    for row in rows:
        for name in row:
            if name not in columns and not name.startswith("_"):
                columns.append(name)
    n_new = n_old + len(rows)
    for name in columns:
        values = [row.get(name) for row in rows]
        if name not in group:
            sample = next((v for v in values if v is not None), None)
            if isinstance(sample, str):
                dtype, fill = _STRING, ""
            elif isinstance(sample, (bool, np.bool_)):
                dtype, fill = np.int8, -1
            elif isinstance(sample, (int, np.integer)):
                dtype, fill = np.int64, -1
            else:
                dtype, fill = np.float64, math.nan
            dataset = group.create_dataset(name, shape=(n_old,), maxshape=(None,), dtype=dtype,
                                           chunks=(_CHUNK,), fletcher32=dtype is not _STRING,
                                           fillvalue=fill)
            dataset.attrs["fill"] = fill
        dataset = group[name]
        fill = dataset.attrs["fill"]
        if h5py.check_string_dtype(dataset.dtype) is not None:
            array = np.asarray(["" if v is None else str(v) for v in values], dtype=object)
            before = dataset.attrs.get(STRINGS_SEAL)
            if before is None:  # a new column, or one of a store made before strings were sealed
                before = strings_checksum(dataset.asstr()[()]) if n_old else 0
            dataset.attrs[STRINGS_SEAL] = np.uint32(strings_checksum(array, int(before)))
        else:
            array = np.asarray([fill if v is None else v for v in values], dtype=dataset.dtype)
        dataset.resize((n_new,))
        dataset[n_old:n_new] = array
    group.attrs["n_rows"] = n_new
    group.attrs["columns_json"] = json.dumps(columns)


def _seal(handle: h5py.File) -> None:
    """Seal the attributes of the root, every group and every column, the values of every numeric column
    and the strings of every string column not sealed yet (a store made before seals), and bind every
    column to the study (:mod:`.binding`), as the last step of every write."""
    handle.attrs["schema_version"] = SCHEMA_VERSION
    key = study_key(handle)
    for group_name in ("settings", "metrics", "cells"):
        group = handle[group_name]
        for name in group:
            dataset = group[name]
            path = f"/{group_name}/{name}"
            if h5py.check_string_dtype(dataset.dtype) is None:
                dataset.attrs[DATA_SEAL] = seal = data_digest(path, dataset[()])
            else:
                if STRINGS_SEAL not in dataset.attrs:
                    dataset.attrs[STRINGS_SEAL] = np.uint32(strings_checksum(dataset.asstr()[()]))
                seal = int(dataset.attrs[STRINGS_SEAL])
            dataset.attrs[binding.BINDING] = binding.column_binding(key, path, seal)
            seal_attrs(dataset)
        seal_attrs(group)
    seal_attrs(handle)


def _make_folders(folder: Path) -> list[Path]:
    """Make ``folder`` and its missing parents; the ones made, outermost first."""
    missing = []
    while not folder.exists() and folder != folder.parent:
        missing.append(folder)
        folder = folder.parent
    for item in reversed(missing):
        item.mkdir(exist_ok=True)
    return list(reversed(missing))


#: Room kept free beyond what a write needs, bytes.
_MARGIN = 1 << 20


def _ensure_room(folder: Path, needed: int) -> None:
    """Refuse a write that would not fit (free disk space, ``ulimit -f``) before any byte is written:
    HDF5 running out of space mid-write can crash the process instead of raising."""
    import resource

    needed = int(needed) + _MARGIN
    try:
        stats = os.statvfs(folder)
        free = stats.f_bavail * stats.f_frsize
    except OSError:
        free = None
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if free is not None and free < needed:
        raise StudyStoreError(f"{folder}: not enough free disk space for the study store ({free} bytes free, "
                              f"{needed} needed); every cell committed before is kept")
    if limit != resource.RLIM_INFINITY and limit < needed:
        raise StudyStoreError(f"{folder}: the file size limit (ulimit -f: {limit} bytes) is below the "
                              f"{needed} bytes the study store needs; every cell committed before is kept")


def check_usable(path: Path, header: dict, *, overwrite: bool = False, replace_stale: bool = False,
                 require_existing: bool = False) -> bool:
    """Whether the study store at ``path`` can take the study of ``header``, checked without writing or
    locking: :class:`StudyStore` checks this on opening, and ``ilcforce study A.toml B.toml`` checks
    every file's store before any cell runs (a stale B was found only after A's cells had run).

    Returns True when the store is to be made anew (none yet; ``overwrite``; a stored study with other
    settings or code and ``replace_stale``), False when it is continued. Raises
    :class:`StudyStoreError` (one line) when it may not be touched.
    """
    path = Path(path)
    if overwrite and require_existing:
        raise StudyStoreError(f"{path}: --overwrite and --resume are mutually exclusive; choose one")
    if os.path.lexists(path) and (path.is_symlink() or not path.is_file()):
        raise StudyStoreError(f"{path}: exists and is not a regular file; refusing to touch it")
    if not path.exists():
        if require_existing:
            raise StudyStoreError(f"{path}: no study store to resume (run without --resume to start it)")
        return True
    if not is_study_store(path):
        why = f"{path}: exists and is not an ilcforce study store"
        if is_hdf5_file(path):  # say which: another HDF5 file, or a damaged study store
            try:
                read_header(path)
            except StudyStoreError as error:
                why = one_line(str(error))
        raise StudyStoreError(f"{why}; refusing to replace it (move it away)")
    stored = read_header(path)
    reason = None
    if stored.get("definition_json") != header["definition_json"]:
        reason = ("its study has different settings ("
                  + (settings_difference(str(stored.get("definition_json")), header["definition_json"])
                     or "sweep, fixed values or experiment") + ")")
    elif stored.get("fingerprint") != header["fingerprint"]:
        reason = "its cells were computed by different simulation code"
    if overwrite or (reason and replace_stale):
        return True
    if reason:
        raise StudyStoreError(f"{path}: {reason}; pass --overwrite to start the study over")
    return False


def settings_difference(stored: str, new: str) -> str:
    """The first difference between two studies' definitions (JSON), stored -> new, for the refusal:
    e.g. "setting 1: c3.eta 2.0 -> 3.0"; '' when it cannot be told."""
    from ilcforce.config_load import _flat as flat  # the config's own dotted keys

    try:
        was, now = json.loads(stored), json.loads(new)
        if was.get("sweep_keys") != now.get("sweep_keys"):
            return f"setting columns {was.get('sweep_keys')} -> {now.get('sweep_keys')}"
        if len(was["settings"]) != len(now["settings"]):
            return f"{len(was['settings'])} settings -> {len(now['settings'])}"
        if was.get("labels") != now.get("labels"):
            return f"setting labels {was.get('labels')} -> {now.get('labels')}"
        for k, (a, b) in enumerate(zip(was["settings"], now["settings"])):
            a, b = flat(json.loads(a)), flat(json.loads(b))
            keys = sorted(key for key in a.keys() | b.keys() if a.get(key) != b.get(key))
            if keys:
                more = f" and {len(keys) - 1} more key(s)" if len(keys) > 1 else ""
                return f"setting {k}: {keys[0]} {a.get(keys[0], '-')} -> {b.get(keys[0], '-')}{more}"
    except (ValueError, TypeError, AttributeError, KeyError):
        pass
    return ""


class StudyStore:
    """The driver's handle on a study store: lock, compatibility check, journal, consolidation.

    Parameters
    ----------
    path : Path
        ``results/studies/<name>.h5``.
    header : dict
        Root attributes for a new store: ``name``, ``description``, ``study_toml``,
        ``definition_json``, ``fingerprint``; plus ``settings``: a list of dicts with
        ``config_json``, ``label``, ``values_json``.
    session : dict
        Provenance of this run (command, scheduler, workers, versions), appended to ``sessions_json``.
    overwrite : bool
        Start over: an existing study store (and its journal) is replaced. Never replaces a file
        that is not a study store.
    replace_stale : bool
        Start over when the stored study has different settings or was made by different code,
        instead of refusing.
    require_existing : bool
        ``--resume``: refuse when there is no store to continue.
    """

    def __init__(self, path: Path, *, header: dict, session: dict, overwrite: bool = False,
                 replace_stale: bool = False, require_existing: bool = False,
                 consolidate_every: float = 2.0) -> None:
        self.path = Path(path)
        self._header = header
        self._session = dict(session)
        self._pending: list[dict] = []
        self.consolidate_every = consolidate_every
        self._made_folders = _make_folders(self.path.parent)
        self._lock_fd = self._lock()
        self.created = not self.path.exists()  # this handle makes the store (see discard_if_unused)
        self.committed = 0
        self.quarantined: list[str] = []  # one line per refused journal record moved aside
        try:
            self._remove_dead_copies()
            self._prepare(overwrite, replace_stale, require_existing)
            self._open_journal()
        except BaseException:
            self.close()
            raise

    def _open_journal(self) -> None:
        """Read what the store and its journal hold: the journal's records are checked against the
        store (:mod:`.study_journal`), the refused ones moved aside. A store made before stores had
        an identity, or a run that plans cells no earlier run planned, is consolidated at once, so
        that every record this run commits is a cell of the study as the store itself tells it."""
        stored = read_header(self.path, check=False)
        self._study_id = str(stored.get("study_id", "")) or uuid.uuid4().hex
        plan = (self._session.get("seeds"), self._session.get("methods"))
        current = {**stored, "study_id": self._study_id,
                   "sessions_json": json.dumps([*json.loads(str(stored.get("sessions_json", "[]"))), self._session])}
        self._facts = study_facts(current)
        found = scan_journal(self.path, current)
        for item, why in found.refused:
            try:
                where = records.quarantine(item, study_journal.QUARANTINE)
            except OSError as exc:
                raise StudyStoreError(f"{item}: a refused journal record ({why}) cannot be moved aside "
                                      f"({exc.strerror or exc})") from None
            self.quarantined.append(f"{item}: {why}; moved to {where}, its cell runs again")
        self.done: set[tuple[int, int, str]] = set()
        self.failed: dict[tuple[int, int, str], str] = {}
        with h5py.File(self.path, "r") as handle:
            stored_cells = _table(handle["cells"])
            self._sessions = json.loads(handle.attrs.get("sessions_json", "[]"))
        self._in_file = set(_keys(stored_cells[stored_cells["state"] == DONE])) if len(stored_cells) else set()
        states = list(zip(_keys(stored_cells), stored_cells["state"], stored_cells["message"])) if len(
            stored_cells) else []
        states += [((r["setting"], r["seed"], r["method"]), r["state"], r["message"]) for r in found.records]
        for key, state, message in states:
            if state == DONE:
                self.done.add(key)
                self.failed.pop(key, None)
            elif key not in self.done:
                self.failed[key] = str(message)
        self._pending = list(found.records)
        self._last = 0.0
        planned = all(plan) and all(any(s in seeds and m in methods for seeds, methods in
                                        study_facts(stored).plans) for s in plan[0] for m in plan[1])
        if not stored.get("study_id") or not planned:
            self._consolidate(0.0)

    # -- setup --------------------------------------------------------------------------------

    def _lock(self) -> int:
        try:
            return acquire_writer_lock(self.path, f"{self.path}: another ilcforce study is writing this store")
        except StoreError as exc:
            raise StudyStoreError(str(exc)) from None

    def _remove_dead_copies(self) -> None:
        """Remove what a killed driver of this study left half written: ``.<name>.h5.tmp-<pid>`` beside
        the store and ``.<record>.tmp-<pid>`` in its journal, of processes that are gone, each by its
        exact name (we hold the study's lock: no live driver of it is writing one)."""
        stale = dead_writers_copies(self.path)
        if journal_dir(self.path).is_dir() and not journal_dir(self.path).is_symlink():
            stale += dead_copies_in(journal_dir(self.path))
        for item in dict.fromkeys(stale):
            with contextlib.suppress(OSError):
                item.unlink()

    def _prepare(self, overwrite: bool, replace_stale: bool, require_existing: bool) -> None:
        if check_usable(self.path, self._header, overwrite=overwrite, replace_stale=replace_stale,
                        require_existing=require_existing):
            self._clear_journal()
            self._create()

    def _clear_journal(self) -> None:
        folder = journal_dir(self.path)
        if folder.is_dir() and not folder.is_symlink():
            for item in folder.iterdir():
                if item.is_file() and (item.suffix == ".json" or ".tmp-" in item.name):
                    item.unlink()

    def _create(self) -> None:
        _ensure_room(self.path.parent, 512 * 1024 + 2 * len(json.dumps(self._header["settings"])))

        def build(handle: h5py.File) -> None:
            handle.attrs.update({"schema": SCHEMA_NAME, "schema_version": SCHEMA_VERSION, "study_id": uuid.uuid4().hex,
                                 "sessions_json": json.dumps([self._session]),
                                 **{key: str(self._header.get(key, "")) for key in (
                                     "name", "description", "study_toml", "definition_json", "fingerprint", "created")}})
            _append(handle.create_group("settings"), list(self._header["settings"]))
            handle.create_group("metrics").attrs["n_rows"] = 0
            handle.create_group("cells").attrs["n_rows"] = 0
            _seal(handle)

        try:
            commit.create(self.path, build)
        except StoreError as exc:
            raise StudyStoreError(str(exc)) from None

    # -- committing ---------------------------------------------------------------------------

    def commit(self, record: dict, now: float) -> None:
        """Commit one cell's record (``setting``, ``seed``, ``method``, ``state``, ``attempts``,
        ``message``, ``elapsed``, ``worker``, ``rows``) to the journal; consolidate if due."""
        with stops.critical():  # a stop signal takes effect when the commit has ended
            if not check_writer_lock(self._lock_fd):
                raise StudyStoreError(f"{self.path}: its lock file was deleted or replaced while this study held it, "
                                      "so another driver may be in; stopping (every committed cell is kept)")
            folder = journal_dir(self.path)
            folder.mkdir(exist_ok=True)
            target = folder / study_journal.record_name(record["setting"], record["seed"], record["method"])
            record = study_journal.seal(record, self._study_id, self._facts.digests[record["setting"]])
            try:  # never commit a record that a reader would refuse
                study_journal.check(record, self._facts)
            except study_journal.RecordError as exc:
                raise StudyStoreError(f"{target}: refusing to commit the cell ({exc})") from None
            text = json.dumps(record)
            _ensure_room(folder, 2 * len(text))
            try:
                records.atomic_write(target, text.encode())
            except OSError as exc:
                raise StudyStoreError(f"{target}: cannot commit the cell ({exc.strerror or exc}); every cell "
                                      "committed before is kept, rerun to continue") from None
            self.committed += 1
            self._pending.append({**record, "_file": target})
            key = (int(record["setting"]), int(record["seed"]), str(record["method"]))
            if record["state"] == DONE:
                self.done.add(key)
                self.failed.pop(key, None)
            else:
                self.failed[key] = str(record.get("message", ""))
            if now - self._last >= self.consolidate_every:
                self.consolidate(now)

    def consolidate(self, now: float = 0.0) -> None:
        """Fold the journal into the HDF5 file (copy, append, fsync, rename), then clear it. A stop
        signal takes effect after it (h5py can swallow a KeyboardInterrupt raised in its write-back:
        :mod:`ilcforce.stops`)."""
        with stops.critical():
            self._consolidate(now)

    def _consolidate(self, now: float = 0.0) -> None:
        self._last = now
        cells, rows, added = fold(self._pending, self._in_file)
        sessions = list(self._sessions)
        if not sessions or sessions[-1].get("id") != self._session.get("id"):
            sessions.append(self._session)
        else:
            sessions[-1] = self._session
        # the copy, what is appended (8 bytes a value, doubled for strings) and new chunks (8 kB a column)
        _ensure_room(self.path.parent, 2 * self.path.stat().st_size + 16 * sum(len(r) for r in rows)
                     + 4096 * len(cells) + 8192 * 64)

        def change(handle: h5py.File) -> None:
            _append(handle["cells"], cells)
            _append(handle["metrics"], rows)
            handle.attrs["sessions_json"] = json.dumps(sessions)
            handle.attrs["study_id"] = self._study_id
            _seal(handle)

        try:
            commit.replace(self.path, change)
        except StoreError as exc:
            raise StudyStoreError(f"{self.path}: cannot consolidate the study store ({exc}); every committed cell "
                                  "is kept in its journal, rerun to continue") from None
        self._in_file |= added
        self._sessions = sessions
        for record in self._pending:
            try:
                record["_file"].unlink()
            except FileNotFoundError:
                pass
        self._pending = []

    def update_session(self, **fields) -> None:
        self._session.update(fields)

    def discard_if_unused(self) -> None:
        """Remove the store this handle made when no cell was committed to it (the cluster could not
        be reached, the run was stopped before its first cell): no empty study is left behind for a
        later --resume or report to pick up. A store that existed before is never touched."""
        if not self.created or self.committed or getattr(self, "_lock_fd", None) is None:
            return
        for leftover in (self.path, writers_lock(self.path)):
            leftover.unlink(missing_ok=True)
        with contextlib.suppress(OSError):
            journal_dir(self.path).rmdir()  # only if empty
        self.close()
        for folder in reversed(self._made_folders):  # e.g. results/studies/: only the ones made here, if empty
            with contextlib.suppress(OSError):
                folder.rmdir()

    def close(self) -> None:
        if getattr(self, "_lock_fd", None) is not None:
            os.close(self._lock_fd)
            self._lock_fd = None
