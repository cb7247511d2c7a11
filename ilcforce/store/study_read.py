"""Reading the study store, ``results/studies/<name>.h5`` and its journal: header, metrics and cell
tables (:func:`read_tables`), and what identifies a study store. The writer is :mod:`.study`."""


from __future__ import annotations

import json
import os
from pathlib import Path

import h5py
import numpy as np
import pandas as pd

from ilcforce.store.safeio import is_hdf5_file
from ilcforce.store.schema import STUDY_NAME, STUDY_SCHEMA_NAME

SCHEMA_NAME = STUDY_SCHEMA_NAME
SCHEMA_VERSION = "1.0"
CELL_COLUMNS = ("setting", "seed", "method", "state", "attempts", "message", "elapsed", "worker")
KEY_COLUMNS = ("setting", "seed", "method")
DONE, FAILED = "done", "failed"
_STRING = h5py.string_dtype("utf-8")
_CHUNK = 1024


class StudyStoreError(Exception):
    """A study store that cannot be used (locked, foreign, damaged, a different study); one line."""


def journal_dir(path: Path) -> Path:
    return Path(f"{path}.journal")


def _lock_path(path: Path) -> Path:
    return Path(f"{path}.lock")


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


def _column(dataset: h5py.Dataset) -> np.ndarray:
    if h5py.check_string_dtype(dataset.dtype) is not None:
        return np.asarray(dataset.asstr()[()], dtype=object)
    return dataset[()]


def _table(group: h5py.Group) -> pd.DataFrame:
    n = int(group.attrs.get("n_rows", 0))
    data = {}
    for name in json.loads(group.attrs.get("columns_json", "[]")):
        values = _column(group[name])
        if values.shape != (n,):
            raise StudyStoreError(f"{group.file.filename}: /{group.name.strip('/')}/{name} has {values.shape[0]} "
                                  f"rows, expected {n}")
        data[name] = values
    return pd.DataFrame(data)


#: How :func:`ignored_journal_entries` names a .json that is not a readable cell record.
DAMAGED_RECORD = "not a cell record (damaged or foreign)"


def _read_record(item: Path) -> dict | None:
    """A journal file's cell record; None when it is damaged or not one (its cell runs again)."""
    if not item.is_file():  # a FIFO (or a device) would block the read for ever
        return None
    try:
        record = json.loads(item.read_text(encoding="utf-8"))
    except (OSError, ValueError, UnicodeDecodeError):
        return None
    if not isinstance(record, dict) or not all(k in record for k in (*KEY_COLUMNS, "state", "rows")):
        return None
    record["_file"] = item
    return record


def _journal_records(path: Path) -> list[dict]:
    folder = journal_dir(path)
    if not folder.is_dir():
        return []
    records = (_read_record(item) for item in sorted(folder.iterdir())
               if item.suffix == ".json" and not item.name.startswith("."))
    return [record for record in records if record is not None]


def ignored_journal_entries(path: Path) -> list[str]:
    """What the journal folder holds that readers skip, each as 'name: why', in one pass over it (a
    record committed meanwhile is not taken for a damaged one): a damaged or foreign .json (its cell
    runs again), a folder, another file. Hidden files (a record being written) are left out."""
    folder = journal_dir(path)
    if not folder.is_dir():
        return []
    found = []
    for item in sorted(folder.iterdir()):
        if item.name.startswith("."):
            continue
        if item.is_dir():
            found.append(f"{item.name}: a folder")
        elif not item.is_file():
            found.append(f"{item.name}: not a regular file")
        elif item.suffix != ".json":
            found.append(f"{item.name}: not a .json record")
        elif _read_record(item) is None:
            found.append(f"{item.name}: {DAMAGED_RECORD}")
    return found


def latest_study_toml(sessions: list, first: str) -> str:
    """The study file as the latest run that recorded it read it (a rerun may add seeds or methods);
    ``first`` (the file the store was made from) for a store from before runs recorded it."""
    files = [s["study_toml"] for s in sessions if isinstance(s, dict) and s.get("study_toml")]
    return str(files[-1]) if files else first


def _probe(path: Path) -> None:
    """Bounded time on a damaged file: walk its structure in a forked child first (the run store's
    :func:`ilcforce.store.safeio.probe`); StudyStoreError if that fails."""
    from ilcforce.store.safeio import StoreError, check_regular_file, probe

    try:
        check_regular_file(Path(path))  # a FIFO would block the open below for ever
    except StoreError as exc:
        raise StudyStoreError(str(exc)) from None
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError as exc:
        raise StudyStoreError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    try:
        probe(Path(path), fd)
    except StoreError as exc:
        raise StudyStoreError(str(exc)) from None
    finally:
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
    extra_rows, extra_cells = [], []
    for record in _journal_records(path):
        key = (int(record["setting"]), int(record["seed"]), str(record["method"]))
        if record["state"] == DONE and key in done:
            continue  # consolidated already (killed between the rename and the journal cleanup)
        extra_cells.append({c: record.get(c) for c in CELL_COLUMNS})
        if record["state"] == DONE:
            extra_rows += [{"setting": key[0], "seed": key[1], "method": key[2], **row} for row in record["rows"]]
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
    return {"name": str(header.get("name", "")), "cells": len(states), "done": states.count(DONE),
            "failed": states.count(FAILED), "ignored": ignored_journal_entries(Path(path))}


# ------------------------------------------------------------------------------------------------
# writing (the driver only)
