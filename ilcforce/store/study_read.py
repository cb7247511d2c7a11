"""Reading the study store, ``results/studies/<name>.h5`` and its journal: header, metrics and cell
tables (:func:`read_tables`), and what identifies a study store. The writer is :mod:`.study`."""


from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

import h5py
import numpy as np
import pandas as pd

from ilcforce.store import binding, study_journal
from ilcforce.store.seal import ATTRS_SEAL, DATA_SEAL, STRINGS_SEAL, attrs_state, data_digest, strings_checksum
from ilcforce.store.filecheck import StoreError, check_links, check_regular_file, is_hdf5_file, probe, writers_lock
from ilcforce.store.schema import STUDY_NAME, STUDY_SCHEMA_NAME

SCHEMA_NAME = STUDY_SCHEMA_NAME
SCHEMA_VERSION = "1.3"
#: From this version on, the root, every group and every column carry attribute seals and every
#: string column a checksum of its values (:mod:`.seal`). A 1.0 store has none: it is read and
#: ``validate`` says its strings are unverified (accepted: its numbers are Fletcher-32 checked, and
#: the driver seals it at its next consolidation).
SEALED_FROM = (1, 1)
#: The first study schema whose numeric columns carry their digest (seal.DATA_SEAL).
DIGESTS_FROM = (1, 2)
#: The first study schema whose columns are bound to their study (:mod:`.binding`): each numeric column's
#: digest and each string column's CRC-32 start from the study's key (its study_id, fingerprint and
#: definition) and the column's path. A 1.2 store is read, and ``validate`` says its columns are not bound;
#: the driver's next consolidation binds it.
BOUND_FROM = (1, 3)
CELL_COLUMNS = ("setting", "seed", "method", "state", "attempts", "message", "elapsed", "worker")
KEY_COLUMNS = ("setting", "seed", "method")
DONE, FAILED = "done", "failed"
_STRING = h5py.string_dtype("utf-8")
_CHUNK = 1024


class StudyStoreError(Exception):
    """A study store that cannot be used (locked, foreign, damaged, a different study); one line."""


def journal_dir(path: Path) -> Path:
    return Path(f"{path}.journal")


def is_study_store(path: Path) -> bool:
    """True if ``path`` is an HDF5 file carrying the study schema (never raises, bounded time)."""
    try:
        if not is_hdf5_file(Path(path)):  # also: a FIFO, which an open would wait on for ever
            return False
        _probe(Path(path))
        with h5py.File(path, "r") as handle:
            return handle.attrs.get("schema") == SCHEMA_NAME
    except Exception:  # noqa: BLE001 - any unreadable file is "not a study store"
        return False


# ------------------------------------------------------------------------------------------------
# reading


def is_sealed(handle: h5py.File, since: tuple[int, int] = SEALED_FROM) -> bool:
    """Whether the study store open as ``handle`` is of a schema whose attributes and strings are
    sealed (``since`` 1.1; its numeric columns: DIGESTS_FROM)."""
    try:
        major, minor = (int(x) for x in str(handle.attrs.get("schema_version", "")).split("."))
    except ValueError:
        return True
    return (major, minor) >= since


def _verify_attrs(obj, sealed: bool) -> None:
    state = attrs_state(obj)
    if state == "damaged" or (state == "unsealed" and sealed):
        what = "root" if obj.name == "/" else obj.name
        raise StudyStoreError(f"{obj.file.filename}: the attributes of {what} do not match their checksum "
                              f"({ATTRS_SEAL}) or have none: damaged")


def study_key(handle: h5py.File) -> bytes | None:
    """The binding key of the study store open as ``handle`` (:func:`.binding.study_key`); None for a
    store of a schema before :data:`BOUND_FROM`."""
    if not is_sealed(handle, BOUND_FROM):
        return None
    attrs = handle.attrs
    study_id = attrs.get("study_id")
    if not isinstance(study_id, str) or not study_id:
        raise StudyStoreError(f"{handle.filename}: no study_id, which schema {attrs.get('schema_version')} requires")
    return binding.study_key(study_id, str(attrs.get("fingerprint", "")), str(attrs.get("definition_json", "")))


def _column(dataset: h5py.Dataset, sealed: bool, path: str, key: bytes | None = None) -> np.ndarray:
    _verify_attrs(dataset, sealed)
    if h5py.check_string_dtype(dataset.dtype) is not None:
        values = np.asarray(dataset.asstr()[()], dtype=object)
        stored = dataset.attrs.get(STRINGS_SEAL)
        if stored is None and not sealed:
            _check_binding(dataset, path, key, None)
            return values
        if stored is None or int(stored) != strings_checksum(values):
            raise StudyStoreError(f"{dataset.file.filename}: the strings of {dataset.name} do not match their "
                                  f"checksum ({STRINGS_SEAL}): damaged")
        _check_binding(dataset, path, key, int(stored))
        return values
    values = dataset[()]
    if DATA_SEAL in dataset.attrs or is_sealed(dataset.file, DIGESTS_FROM):
        if str(dataset.attrs.get(DATA_SEAL)) != data_digest(path, values):
            raise StudyStoreError(f"{dataset.file.filename}: the values of {path} do not match their digest "
                                  f"({DATA_SEAL}): changed after they were written")
    _check_binding(dataset, path, key, dataset.attrs.get(DATA_SEAL))
    return values


def _check_binding(dataset: h5py.Dataset, path: str, key: bytes | None, seal) -> None:
    """The column is bound to its study and path (``key``: :func:`study_key`), or, in a store of a schema
    before :data:`BOUND_FROM` (``key`` None), carries no binding."""
    stored = dataset.attrs.get(binding.BINDING)
    if key is None:
        if stored is not None:
            raise StudyStoreError(f"{dataset.file.filename}: {path} carries a binding, which its schema "
                                  f"{dataset.file.attrs.get('schema_version')} does not have: altered after it was "
                                  "written, or continued by an older ilcforce")
        return
    if seal is None or stored != binding.column_binding(key, path, seal):
        raise StudyStoreError(f"{dataset.file.filename}: {path} is not bound to this study (its {binding.BINDING} does "
                              "not match: copied from another study or column, or changed after it was written)")


def _table(group: h5py.Group) -> pd.DataFrame:
    sealed = is_sealed(group.file)
    _verify_attrs(group, sealed)
    key = study_key(group.file)
    n = int(group.attrs.get("n_rows", 0))
    data = {}
    for name in json.loads(group.attrs.get("columns_json", "[]")):
        values = _column(group[name], sealed, f"{group.name}/{name}", key)
        if values.shape != (n,):
            raise StudyStoreError(f"{group.file.filename}: /{group.name.strip('/')}/{name} has {values.shape[0]} "
                                  f"rows, expected {n}")
        data[name] = values
    return pd.DataFrame(data)


#: How :func:`check_study_store` marks a .json record that readers refuse (its cell runs again).
DAMAGED_RECORD = "refused"


def study_facts(header: dict) -> study_journal.StudyFacts:
    """What the journal's records of the study store with ``header`` (:func:`read_header`) are
    checked against."""
    try:
        sessions = json.loads(str(header.get("sessions_json", "[]")))
    except (ValueError, RecursionError):
        sessions = []
    settings = header["settings"]
    configs = settings["config_json"].tolist() if "config_json" in settings else []
    return study_journal.facts(str(header.get("study_id", "")), str(header.get("fingerprint", "")), configs,
                               sessions if isinstance(sessions, list) else [])


def _journal_folder(path: Path) -> Path:
    """The journal folder of the study store at ``path``; StudyStoreError if it is a symbolic link or a
    mount point (a bind mount: another study's journal, whose records each would quarantine)."""
    folder = journal_dir(path)
    mounted = os.path.ismount(folder)
    with contextlib.suppress(OSError), open("/proc/self/mountinfo", encoding="utf-8") as table:  # Linux: and
        mounted |= os.path.realpath(folder) in {line.split()[4] for line in table}  # a bind mount on one fs
    if folder.is_symlink() or mounted:
        how = f"symbolic link (to {os.readlink(folder)})" if folder.is_symlink() else "mount point (a bind mount?)"
        raise StudyStoreError(f"{folder}: the journal folder is a {how}; a study's journal is its own folder, refusing it")
    if os.path.lexists(folder) and not folder.is_dir():
        raise StudyStoreError(f"{folder}: not a folder; a study's journal is a folder")
    return folder


def scan_journal(path: Path, header: dict) -> study_journal.Scan:
    """Every record of the study store's journal, checked against the store (:mod:`.study_journal`)."""
    return study_journal.scan(_journal_folder(path), study_facts(header))


def fold(records: list[dict], in_file: set) -> tuple[list, list, set]:
    """(cells, metric rows, keys added) of the journal ``records`` whose cell is not done in the file
    yet (``in_file``: (setting, seed, method) keys; one consolidated before a kill -9 removed its record)."""
    cells, rows, added = [], [], set()
    for record in records:
        key = (int(record["setting"]), int(record["seed"]), str(record["method"]))
        if record["state"] == DONE and (key in in_file or key in added):
            continue
        cells.append({c: record.get(c) for c in CELL_COLUMNS})
        if record["state"] == DONE:
            added.add(key)
            rows += [{"setting": key[0], "seed": key[1], "method": key[2], **row} for row in record["rows"]]
    return cells, rows, added


def _entries(found: study_journal.Scan) -> list[str]:
    """What the journal folder holds that readers skip, each as 'name: why': a refused record (its
    cell runs again) with the reason, a folder, another file (hidden ones left out)."""
    entries = [(item.name, f"{DAMAGED_RECORD} ({why})") for item, why in found.refused]
    entries += [(item.name, what) for item, what in found.other]
    return [f"{name}: {why}" for name, why in sorted(entries)]


def latest_study_toml(sessions: list, first: str) -> str:
    """The study file as the latest run that recorded it read it (a rerun may add seeds or methods);
    ``first`` (the file the store was made from) for a store from before runs recorded it."""
    files = [s["study_toml"] for s in sessions if isinstance(s, dict) and s.get("study_toml")]
    return str(files[-1]) if files else first


def _probe(path: Path) -> None:
    """Bounded time on a damaged file: walk its structure in a forked child first (the run store's
    :func:`ilcforce.store.filecheck.probe`); StudyStoreError if that fails."""
    fd = -1
    try:
        check_regular_file(Path(path))  # a FIFO would block the open below for ever
        fd = os.open(path, os.O_RDONLY)
        probe(Path(path), fd)
    except StoreError as exc:
        raise StudyStoreError(str(exc)) from None
    except OSError as exc:
        raise StudyStoreError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    finally:
        if fd >= 0:
            os.close(fd)


def read_header(path: Path, *, check: bool = True) -> dict:
    """Root attributes and the settings table of a study store; StudyStoreError if not one.

    ``check`` walks the file in a time-limited child first (readers; the driver, which wrote the
    file itself, skips it)."""
    if check:
        _probe(path)
    try:
        with h5py.File(path, "r") as handle:
            if handle.attrs.get("schema") != SCHEMA_NAME:
                raise StudyStoreError(f"{path}: not an ilcforce study store")
            version = str(handle.attrs.get("schema_version", ""))
            if version.split(".")[0] != SCHEMA_VERSION.split(".")[0]:
                raise StudyStoreError(f"{path}: study store schema {version!r}; this ilcforce reads {SCHEMA_VERSION}")
            _verify_attrs(handle, is_sealed(handle))
            try:
                check_links(handle, Path(path))  # before any column is read: never another file's data
            except StoreError as exc:
                raise StudyStoreError(str(exc)) from None
            attrs = {k: (v.decode() if isinstance(v, bytes) else v) for k, v in handle.attrs.items()}
            name = attrs.get("name")
            if not isinstance(name, str) or not STUDY_NAME.fullmatch(name) or name in (".", ".."):
                # the name makes the report's folder: never a path from a damaged or edited file
                raise StudyStoreError(f"{path}: damaged study store (its name {str(name)[:60]!r} is not a plain file name)")
            settings = _table(handle["settings"])
    except StudyStoreError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise StudyStoreError(f"{path}: not a readable ilcforce study store ({' '.join(str(exc).split())})") from None
    attrs["settings"] = settings
    return attrs


def read_tables(path: Path, *, check: bool = True) -> tuple[dict, pd.DataFrame, pd.DataFrame]:
    """(header, metrics, cells) of a study store, journal records included.

    ``metrics`` has the raw columns (``setting`` index, ``seed``, ``method``, ``iteration``, metric
    columns); ``cells`` one row per cell, its latest record.
    """
    header = read_header(path, check=check)
    try:
        with h5py.File(path, "r") as handle:
            metrics = _table(handle["metrics"])
            cells = _table(handle["cells"])
    except StudyStoreError:
        raise
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise StudyStoreError(f"{path}: damaged study store ({' '.join(str(exc).split())})") from None
    done = set(_keys(cells[cells["state"] == DONE])) if len(cells) else set()
    extra_cells, extra_rows, _ = fold(scan_journal(path, header).records, done)
    if extra_cells:
        cells = pd.concat([cells, pd.DataFrame(extra_cells)], ignore_index=True)
    if extra_rows:
        metrics = pd.concat([metrics, pd.DataFrame(extra_rows)], ignore_index=True)
    if len(cells):
        cells = cells.drop_duplicates(list(KEY_COLUMNS), keep="last").reset_index(drop=True)
    return header, metrics, cells


def _keys(frame: pd.DataFrame):
    if not len(frame):
        return iter(())
    return zip(frame["setting"].astype(int), frame["seed"].astype(int), frame["method"].astype(str))


def check_study_store(path: Path) -> dict:
    """Read all of the study store at ``path`` as ``ilcforce validate`` does: the header and every
    table, with their checksums, and the journal's records. Returns its name and cell counts
    (``cells``, ``done``, ``failed``) and the journal entries it ignores (``ignored``); raises
    :class:`StudyStoreError` (one line) on any damage."""
    header, _, cells = read_tables(Path(path))
    states = cells["state"].tolist() if len(cells) else []
    found = scan_journal(Path(path), header)
    ignored = _entries(found)
    if found.quarantined:
        ignored.append(f"{study_journal.QUARANTINE}: {found.quarantined} refused record(s) moved aside earlier")
    with h5py.File(path, "r") as handle:
        sealed, bound = is_sealed(handle), is_sealed(handle, BOUND_FROM)
        version = str(handle.attrs.get("schema_version", ""))
    notes = [] if sealed else ["strings and attributes unverified (schema 1.0, written before they were sealed)"]
    if not bound:
        notes.append(f"columns not bound to the study (schema {version}, written before they were: a column copied "
                     "from another study is not detected; the next study run binds them)")
    return {"name": str(header.get("name", "")), "cells": len(states), "done": states.count(DONE),
            "failed": states.count(FAILED), "ignored": ignored, "notes": notes}


# ------------------------------------------------------------------------------------------------
# writing (the driver only)
