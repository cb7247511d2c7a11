"""A study's journal records: sealed when written, checked against their study before anyone uses them.

A finished cell lives as one JSON record in ``<store>.h5.journal/<setting>-<seed>-<method>.json``
until the driver folds it into the HDF5 file; nothing else stands between its bytes and the
study's table, so a record is used only when its seal matches (:mod:`.records`), its ``study`` is
the ``study_id`` of the store beside it (a journal copied from another study is refused record by
record), its ``setting_digest`` is sha256 of the study's simulation fingerprint and the stored
setting's ``config_json``, its key is a cell some run of the study planned and is its file name,
and every field has its type, size and range (metric rows: the metric columns of one task dimension,
:func:`ilcforce.metrics.metric_columns` of 2 or 3, and memory norms, one per
iteration ``0 .. n - 1``, ``n`` at most the setting's ``experiment.iterations``). Readers skip a
refused record and name it (:func:`scan`); the driver moves it aside into ``.quarantine/`` and its
cell runs again. Records of an older ilcforce (no checksum) are refused like damaged ones.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

from ilcforce.metrics import column_kind, columns_dimension
from ilcforce.store import records
from ilcforce.store.records import RecordError  # noqa: F401 - the journal's name for it

#: Version of a journal record's format (records without it are from before checksums).
RECORD_FORMAT = 2
#: The fields of a record, exactly.
RECORD_FIELDS = frozenset({"format", "study", "setting_digest", "setting", "seed", "method", "state", "attempts",
                           "message", "elapsed", "worker", "rows", "checksum"})
#: Where the driver moves a refused record (inside the journal folder; hidden, so readers skip it).
QUARANTINE = ".quarantine"
#: A record larger than this is refused unread, bytes (a 1000-iteration cell is about 1 MB).
MAX_RECORD_BYTES = 16 << 20
#: Longest message or worker string kept in a record, characters.
MAX_TEXT = 4000
#: Most attempts a cell is given (the driver retries once; a margin for future retries).
MAX_ATTEMPTS = 100

_NAME = re.compile(r"(\d{1,9})-(\d{1,19})-([A-Za-z0-9_]{1,64})\.json")
_MEMORY_COLUMN = re.compile(r"memory_(norm|settled|start)_[A-Za-z0-9_]{1,64}")  # metrics.memory_norms
_INT64 = (-(1 << 63), (1 << 63) - 1)
DONE, FAILED = "done", "failed"


def record_name(setting: int, seed: int, method: str) -> str:
    """The file name of the record of a cell."""
    return f"{setting}-{seed}-{method}.json"


def setting_digest(fingerprint: str, config_json: str) -> str:
    """sha256 of the simulation code's fingerprint and a setting's resolved configuration (JSON)."""
    return hashlib.sha256(f"{fingerprint}\0{config_json}".encode()).hexdigest()


def seal(record: dict, study_id: str, digest: str) -> dict:
    """``record`` (a cell's fields) with its format, study identity, setting digest and checksum."""
    return records.seal({**record, "format": RECORD_FORMAT, "study": study_id, "setting_digest": digest})


@dataclass(frozen=True)
class StudyFacts:
    """What a record is checked against: the study store's identity, settings and planned cells."""

    study_id: str  # the store's study_id attribute ('' for a store made before it existed)
    digests: tuple[str, ...]  # per setting: setting_digest(fingerprint, config_json)
    iterations: tuple[int, ...]  # per setting: experiment.iterations (the most rows a cell has)
    plans: tuple[tuple[frozenset, frozenset], ...]  # per run of the study: (seeds, methods)

    def has_cell(self, seed: int, method: str) -> bool:
        return any(seed in seeds and method in methods for seeds, methods in self.plans)


def facts(study_id: str, fingerprint: str, config_jsons: Iterable[str], sessions: Iterable) -> StudyFacts:
    """:class:`StudyFacts` from a study store's attributes, its settings' ``config_json`` and its
    sessions (each run's ``seeds`` and ``methods``; sessions of an older ilcforce plan nothing)."""
    digests, iterations = [], []
    for text in config_jsons:
        text = str(text)
        digests.append(setting_digest(str(fingerprint), text))
        try:
            n = json.loads(text)["experiment"]["iterations"]
        except (ValueError, KeyError, TypeError, RecursionError):
            n = 0
        iterations.append(n if isinstance(n, int) and not isinstance(n, bool) and n > 0 else 0)
    plans = []
    for session in sessions:
        if not isinstance(session, dict):
            continue
        seeds, methods = session.get("seeds"), session.get("methods")
        if (isinstance(seeds, list) and isinstance(methods, list) and all(_is_int(s) for s in seeds)
                and all(isinstance(m, str) for m in methods)):
            plans.append((frozenset(seeds), frozenset(methods)))
    return StudyFacts(str(study_id), tuple(digests), tuple(iterations), tuple(plans))


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and _INT64[0] <= value <= _INT64[1]


def _is_float(value) -> bool:
    return isinstance(value, float) or _is_int(value)


def _text(value, field: str, limit: int = MAX_TEXT) -> None:
    if not isinstance(value, str):
        raise RecordError(f"{field} is {type(value).__name__}, not a string")
    if len(value) > limit:
        raise RecordError(f"{field} is {len(value)} characters long (at most {limit})")


def read_record(item: Path, facts_: StudyFacts) -> dict:
    """The checked record of the journal file ``item``; RecordError saying why it is refused.

    Reads at most :data:`MAX_RECORD_BYTES`, never follows a symbolic link, never blocks on a FIFO.
    """
    match = _NAME.fullmatch(item.name)
    if match is None:
        raise RecordError("its name is not <setting>-<seed>-<method>.json")
    record = records.read_json(item, MAX_RECORD_BYTES)
    check(record, facts_, match.groups())
    return record


def check(record, facts_: StudyFacts, name_key: tuple[str, str, str] | None = None) -> None:
    """RecordError unless ``record`` is a sealed, whole record of a cell of the study ``facts_``
    (stored under the file name whose parts are ``name_key``)."""
    if isinstance(record, dict) and "format" not in record:
        raise RecordError("no checksum (written by an older ilcforce, or not a record)")
    records.check_fields(record, RECORD_FIELDS, "a record")
    if record["format"] != RECORD_FORMAT:
        raise RecordError(f"record format {str(record['format'])[:20]!r}; this ilcforce reads {RECORD_FORMAT}")
    if record["study"] != facts_.study_id or not facts_.study_id:
        raise RecordError("it belongs to another study (its study id is not this store's)")
    setting, seed, method = record["setting"], record["seed"], record["method"]
    if not _is_int(setting) or not _is_int(seed):
        raise RecordError("setting and seed must be integers")
    _text(method, "method", 64)
    if name_key is not None and (str(setting), str(seed), method) != tuple(name_key):
        raise RecordError(f"it holds cell {record_name(setting, seed, method)}, not the cell of its file name")
    if not 0 <= setting < len(facts_.digests):
        raise RecordError(f"setting {setting} is not one of the study's {len(facts_.digests)} settings")
    if record["setting_digest"] != facts_.digests[setting]:
        raise RecordError(f"computed with other values of setting {setting} or other simulation code")
    if not facts_.has_cell(seed, method):
        raise RecordError(f"seed {seed}, method {method!r} is not a cell any run of this study planned")
    state = record["state"]
    if state not in (DONE, FAILED):
        raise RecordError(f"state {str(state)[:20]!r} is neither {DONE!r} nor {FAILED!r}")
    if not _is_int(record["attempts"]) or not 1 <= record["attempts"] <= MAX_ATTEMPTS:
        raise RecordError(f"attempts {str(record['attempts'])[:20]} is not an integer 1 .. {MAX_ATTEMPTS}")
    _text(record["message"], "message")
    _text(record["worker"], "worker", 300)
    elapsed = record["elapsed"]
    if not _is_float(elapsed) or not (math.isnan(elapsed) or 0 <= elapsed < 1e9):
        raise RecordError(f"elapsed {str(elapsed)[:20]} is not a time in s")
    _check_rows(record["rows"], state, facts_.iterations[setting])


def _check_rows(rows, state: str, most: int) -> None:
    if not isinstance(rows, list):
        raise RecordError("rows is not a list")
    if state == FAILED:
        if rows:
            raise RecordError("a failed cell with metric rows")
        return
    if not rows or len(rows) > most:
        raise RecordError(f"{len(rows)} metric rows; a cell of this setting has 1 .. {most}")
    columns = None
    for j, row in enumerate(rows):
        if not isinstance(row, dict):
            raise RecordError(f"row {j} is not an object")
        keys = set(row)
        if columns is None:
            columns = keys
            try:  # the metric columns of one task dimension (metrics.metric_columns), then memory norms
                columns_dimension(k for k in keys if not _MEMORY_COLUMN.fullmatch(str(k)))
            except ValueError as error:
                raise RecordError(f"row 0 {error}") from None
        elif keys != columns:
            raise RecordError(f"row {j} has other columns than row 0")
        if not _is_int(row["iteration"]) or row["iteration"] != j:
            raise RecordError(f"row {j} is iteration {str(row['iteration'])[:20]}, expected {j}")
        for key, value in row.items():
            kind = column_kind(key)
            ok = (_is_int(value) if kind == "int" else
                  isinstance(value, str) and len(value) <= 64 if kind == "str" else _is_float(value))
            if not ok:
                raise RecordError(f"row {j}: {key} = {str(value)[:30]!r} is not a {kind}")


@dataclass(frozen=True)
class Scan:
    """One pass over a journal folder."""

    records: list  # checked records, each with ``_file`` (its Path)
    refused: list  # (Path, reason) of the .json records refused
    other: list  # (Path, what) of entries that are not records (a folder, another file)
    quarantined: int  # records already moved aside into the quarantine folder


def scan(folder: Path, facts_: StudyFacts) -> Scan:
    """Check every record in ``folder`` (sorted by name; hidden entries, a record being written and
    the quarantine, are left out)."""
    records, refused, other = [], [], []
    if not folder.is_dir():
        return Scan(records, refused, other, 0)
    for item in sorted(folder.iterdir()):
        if item.name.startswith("."):
            continue
        if item.is_dir() and not item.is_symlink():
            other.append((item, "a folder"))
        elif item.suffix != ".json" or not (item.is_symlink() or item.is_file()):
            other.append((item, "not a .json record" if item.is_file() else "not a regular file"))
        else:
            try:
                records.append({**read_record(item, facts_), "_file": item})
            except RecordError as error:
                refused.append((item, str(error)))
    moved = folder / QUARANTINE
    return Scan(records, refused, other, len(os.listdir(moved)) if moved.is_dir() and not moved.is_symlink() else 0)
