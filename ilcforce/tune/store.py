"""The tuning store, ``results/tuning/<name>/`` (beside ``results/studies/``): one JSON record per
finished trial, written as it finishes, so a rerun after ``kill -9`` repeats none of them.

Layout (schema ``ilcforce.tuning`` 1)::

    <name>/tuning.json                 schema, schema_version, name, tuning_toml, definition_json,
                                       fingerprint, created, sessions (command, host, start time)
    <name>/trials/<method>-<n>.json    one finished trial (n zero-padded to 5 digits): TRIAL_KEYS
    <name>/tuned.toml                  the best gains as an experiment file (written after each run)
    <name>/.lock                       flock: one driver at a time

A record is written to a temporary name, fsynced and renamed (whole or absent), so the trials on
disk are always a prefix of finished work. Plain JSON, not HDF5: a trial is a few hundred bytes of
numbers, and the records must be readable while a driver is still writing them.
:func:`validate_tuning` checks a store (``ilcforce validate`` can call it on a directory).
"""

from __future__ import annotations

import fcntl
import json
import math
import os
import re
import shutil
from pathlib import Path

SCHEMA_NAME = "ilcforce.tuning"
SCHEMA_VERSION = 1
HEADER = "tuning.json"
TRIALS = "trials"
TUNED = "tuned.toml"
#: Keys of a trial record: what it is (method, number, params: the sampled values, Optuna's names;
#: empty for trial 0, the experiment's gains), the gains it ran (dotted --set keys), state
#: ("complete" or "failed"), value (the objective, null when failed), per seed the objective (null:
#: diverged) and the RMS error norms per iteration run, message (why it failed), elapsed (s, wall
#: time of its cells added up), in_sampler (whether the sampler learned from it).
TRIAL_KEYS = ("method", "number", "params", "gains", "state", "value", "seeds", "message", "elapsed",
              "in_sampler")
SEED_KEYS = ("seed", "value", "iterations_run", "diverged_iteration", "position_error_rms", "force_error_rms")
COMPLETE, FAILED = "complete", "failed"
_TRIAL_FILE = re.compile(r"(?P<method>[a-z0-9][a-z0-9-]*)-(?P<number>\d{5})\.json")


class TuningStoreError(Exception):
    """A tuning store that cannot be used or is not valid; one line."""


def tuning_dir(results_dir: Path | str, name: str) -> Path:
    return Path(results_dir) / "tuning" / name


def _write_json_atomic(path: Path, data: dict) -> None:
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w", encoding="utf-8") as handle:
            json.dump(data, handle, allow_nan=False)
            handle.flush()
            os.fsync(handle.fileno())
        os.replace(tmp, path)
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise TuningStoreError(f"{path}: cannot write ({exc.strerror or exc}); every trial stored before is kept") from None


def _finite_or_none(value):
    return None if value is None or not math.isfinite(value) else float(value)


class TuningStore:
    """The writer of one tuning store (the driver is the only writer). Opening it locks it, checks a
    stored tuning against ``header`` (same definition and simulation code, unless ``overwrite``)
    and reads the trials already finished (:attr:`trials`, per method a dict number -> record)."""

    def __init__(self, path: Path, header: dict, *, overwrite: bool = False) -> None:
        self.path = Path(path)
        if self.path.is_symlink() or (self.path.exists() and not self.path.is_dir()):
            raise TuningStoreError(f"{self.path}: exists and is not a directory; refusing to touch it")
        if self.path.exists() and any(self.path.iterdir()) and not (self.path / HEADER).is_file():
            raise TuningStoreError(f"{self.path}: exists and is not an ilcforce tuning store; move it away")
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock = os.open(self.path / ".lock", os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        except OSError as exc:
            raise TuningStoreError(f"{self.path}: cannot open the tuning store ({exc.strerror or exc})") from None
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(self._lock)
            raise TuningStoreError(f"{self.path}: another `ilcforce tune` is writing this tuning store") from None
        try:
            self._open(header, overwrite)
        except BaseException:
            self.close()
            raise

    def _open(self, header: dict, overwrite: bool) -> None:
        stored = None
        if (self.path / HEADER).is_file():
            stored = read_header(self.path)
            reason = None
            if stored["definition_json"] != header["definition_json"]:
                reason = "its tuning file defines another search (experiment, methods, seeds, ranges or objective)"
            elif stored["fingerprint"] != header["fingerprint"]:
                reason = "its trials were computed by different simulation code"
            if reason and not overwrite:
                raise TuningStoreError(f"{self.path}: {reason}; pass --overwrite to start the tuning over")
            if overwrite:
                stored = None
        self.created = stored is None and not (self.path / HEADER).exists()
        if stored is None:
            shutil.rmtree(self.path / TRIALS, ignore_errors=True)
            (self.path / TUNED).unlink(missing_ok=True)
            self.header = {**header, "sessions": []}
        else:
            self.header = {**stored, "sessions": list(stored.get("sessions", []))}
        (self.path / TRIALS).mkdir(exist_ok=True)
        self.trials = read_trials(self.path)

    def start_session(self, session: dict) -> None:
        self.header["sessions"].append(session)
        _write_json_atomic(self.path / HEADER, self.header)

    def commit(self, record: dict) -> None:
        """Store one finished trial (whole or not at all)."""
        missing = [k for k in TRIAL_KEYS if k not in record]
        if missing:
            raise ValueError(f"trial record lacks {missing}")
        record = {**record, "value": _finite_or_none(record["value"])}
        name = f"{record['method']}-{record['number']:05d}.json"
        _write_json_atomic(self.path / TRIALS / name, record)
        self.trials.setdefault(record["method"], {})[record["number"]] = record

    def write_tuned(self, text: str) -> Path:
        path = self.path / TUNED
        tmp = path.with_name(f".{TUNED}.tmp-{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
        return path

    def discard_if_unused(self) -> None:
        """Remove a store this run made and stored no trial in (e.g. the scheduler was unreachable)."""
        if self.created and not any(self.trials.values()):
            for name in (HEADER, TUNED):
                (self.path / name).unlink(missing_ok=True)
            shutil.rmtree(self.path / TRIALS, ignore_errors=True)
            (self.path / ".lock").unlink(missing_ok=True)
            self.close()
            try:
                self.path.rmdir()
            except OSError:  # something else is in there: leave the folder
                pass

    def close(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None


def read_header(path: Path) -> dict:
    try:
        header = json.loads((Path(path) / HEADER).read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise TuningStoreError(f"{path}: cannot read {HEADER} ({getattr(exc, 'strerror', None) or exc})") from None
    if not isinstance(header, dict) or header.get("schema") != SCHEMA_NAME:
        raise TuningStoreError(f"{path}: {HEADER} is not an ilcforce tuning header")
    if header.get("schema_version") != SCHEMA_VERSION:
        raise TuningStoreError(f"{path}: tuning schema version {header.get('schema_version')!r}, this ilcforce "
                               f"reads {SCHEMA_VERSION}")
    for key in ("name", "tuning_toml", "definition_json", "fingerprint", "created"):
        if not isinstance(header.get(key), str):
            raise TuningStoreError(f"{path}: {HEADER} lacks {key}")
    return header


def read_trials(path: Path) -> dict[str, dict[int, dict]]:
    """Every stored trial record: method -> {number: record}. Temporary files are skipped."""
    out: dict[str, dict[int, dict]] = {}
    folder = Path(path) / TRIALS
    if not folder.is_dir():
        return out
    for file in sorted(folder.iterdir()):
        match = _TRIAL_FILE.fullmatch(file.name)
        if match is None:
            continue
        try:
            record = json.loads(file.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise TuningStoreError(f"{file}: not a readable trial record ({exc})") from None
        _check_record(file, record, match)
        out.setdefault(record["method"], {})[record["number"]] = record
    return out


def _check_record(file: Path, record, match) -> None:
    def bad(why: str):
        raise TuningStoreError(f"{file}: {why}")

    if not isinstance(record, dict):
        bad("not a JSON object")
    missing = [k for k in TRIAL_KEYS if k not in record]
    if missing:
        bad(f"lacks {', '.join(missing)}")
    if record["method"] != match["method"] or record["number"] != int(match["number"]):
        bad("its method or number differs from its file name")
    if record["state"] not in (COMPLETE, FAILED):
        bad(f"state must be {COMPLETE!r} or {FAILED!r}, got {record['state']!r}")
    value = record["value"]
    if record["state"] == COMPLETE and not isinstance(value, (int, float)):
        bad("a complete trial needs a numeric value")
    if record["state"] == FAILED and value is not None:
        bad("a failed trial has no value")
    if not isinstance(record["params"], dict) or not isinstance(record["gains"], dict):
        bad("params and gains must be tables")
    if not isinstance(record["seeds"], list):
        bad("seeds must be a list")
    for entry in record["seeds"]:
        if not isinstance(entry, dict) or any(k not in entry for k in SEED_KEYS):
            bad(f"each seed entry needs {', '.join(SEED_KEYS)}")


def validate_tuning(path: Path | str) -> dict:
    """Check a tuning store; returns {name, methods: {method: (trials, failed, best value)}}.

    Raises :class:`TuningStoreError` (one line) for a missing or damaged header, a damaged record, a
    gap in a method's trial numbers, or a record of a method the tuning file does not name."""
    path = Path(path)
    header = read_header(path)
    try:
        definition = json.loads(header["definition_json"])
    except ValueError:
        raise TuningStoreError(f"{path}: definition_json is not JSON") from None
    methods = definition.get("methods", [])
    trials = read_trials(path)
    summary = {}
    for method, records in trials.items():
        if method not in methods:
            raise TuningStoreError(f"{path}: trial records of {method!r}, which the tuning does not tune")
        numbers = sorted(records)
        if numbers != list(range(len(numbers))):
            gap = next(i for i, n in enumerate(numbers) if n != i)
            raise TuningStoreError(f"{path}: {method}'s trial {gap} is missing before trial {numbers[gap]}")
        values = [r["value"] for r in records.values() if r["state"] == COMPLETE]
        summary[method] = (len(records), sum(r["state"] == FAILED for r in records.values()),
                           min(values) if values else None)
    return {"name": header["name"], "methods": summary}


def is_tuning_store(path: Path | str) -> bool:
    return Path(path).is_dir() and (Path(path) / HEADER).is_file()


def trials_frame(path: Path | str):
    """Every stored trial as a tidy table (pandas DataFrame), one row per (method, trial), in trial
    order: method, trial, state, objective (NaN when failed), best_so_far (the method's best up to
    and including this trial, NaN before the first complete one), message, elapsed (s), then one
    column per gain (dotted key; a vector gain holds a list). What a report draws the objective
    against the trial number from, and what a reader filters."""
    import pandas as pd

    rows = []
    for method, records in read_trials(path).items():
        best = math.inf
        for number in sorted(records):
            record = records[number]
            value = record["value"] if record["state"] == COMPLETE else math.nan
            if value == value:
                best = min(best, value)
            rows.append({"method": method, "trial": number, "state": record["state"], "objective": value,
                         "best_so_far": best if best < math.inf else math.nan, "message": record["message"],
                         "elapsed": record["elapsed"], **record["gains"]})
    return pd.DataFrame(rows, columns=None if rows else ["method", "trial", "state", "objective", "best_so_far",
                                                          "message", "elapsed"])
