"""The tuning store, ``results/tuning/<name>/`` (layout: docs/store-format.md): a sealed header
``tuning.json``, one sealed JSON record per finished trial in ``trials/``, written as it finishes, and one
per front point re-evaluated on the held-out seeds in ``heldout/``, so a rerun after ``kill -9`` repeats
none of them.

Durability is the study journal's, from the same code (:mod:`.records`): whole-or-absent writes (a
trial by a hard link that never replaces a finished one), sha256 seals, reads in bounded time. The
folder is the writer's lock (:func:`~.safeio.acquire_writer_lock`). A record is trusted only when it
is sealed, carries this store's ``tuning_id`` and its search's digest (definition and simulation
code), names a method and a budget some run of the search asked for, has the search's seeds, a value
that is the median of theirs, and passes the search's own ``check`` (:mod:`ilcforce.tune.runner`:
params in the space, gains from the params, seed values from the error norms). Readers skip any
other record and name it; the writer moves it aside into ``trials/.quarantine/`` (its trial runs again).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
import shutil
import statistics
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ilcforce.records import TASK_DIMENSIONS, task_axes
from ilcforce.store import records
from ilcforce.store.records import RecordError
from ilcforce.store.safeio import StoreError, acquire_writer_lock, check_writer_lock, dead_copies_in
from ilcforce.store.study_journal import _is_int  # an integer, not a bool
from ilcforce.tomlfile import MAX_TOML_BYTES, UnreadableFile, read_regular

SCHEMA_NAME = "ilcforce.tuning"
SCHEMA_VERSION = 3
HEADER, TRIALS, HELDOUT, TUNED = "tuning.json", "trials", "heldout", "tuned.toml"
HEADER_FIELDS = frozenset({"schema", "schema_version", "name", "description", "tuning_toml", "definition_json",
                           "fingerprint", "created", "tuning_id", "sessions", "checksum"})
#: A trial's fields (docs/store-format.md says what each holds).
RECORD_FIELDS = frozenset({"tuning", "search", "method", "number", "params", "gains", "state", "value", "chattering",
                           "feasible", "cap", "scored", "seeds", "checks", "message", "elapsed", "in_sampler",
                           "checksum"})


def seed_keys(axes: tuple[str, ...]) -> tuple[str, ...]:
    """A scoring seed's fields on a task of ``axes``: its settled H per axis (``chattering_task_<a>_settled``)."""
    return ("seed", "value", "chattering", "iterations_run", "diverged_iteration", "position_error_rms",
            "force_error_rms", *(f"chattering_task_{a}_settled" for a in axes))


def check_keys(axes: tuple[str, ...]) -> tuple[str, ...]:
    """A check seed's fields on a task of ``axes``: its last settled H per axis (``h_<a>_last``)."""
    return ("seed", "iterations_run", "planned", "diverged_iteration", "verdict", "text",
            *(f"h_{a}_last" for a in axes))


def heldout_keys(axes: tuple[str, ...]) -> tuple[str, ...]:
    """A held-out seed's fields on a task of ``axes``: its last settled H per axis (``h_<a>``)."""
    return ("seed", "iterations_run", "diverged_iteration", "e_p", "e_f", *(f"h_{a}" for a in axes), "verdict", "text")


#: Every task's axes a record may be of (the planar task's x, y; a plane's u, v, n).
AXES = tuple(task_axes(n) for n in TASK_DIMENSIONS)
#: A held-out evaluation's fields (its seeds': :func:`heldout_keys`).
HELDOUT_FIELDS = frozenset({"tuning", "search", "method", "number", "gains", "seeds", "checksum"})
COMPLETE, FAILED = "complete", "failed"
MAX_BYTES = 16 << 20
_TRIAL_FILE = re.compile(r"(?P<method>[a-z0-9][a-z0-9-]{0,63})-(?P<number>\d{5})\.json")
Check = Callable[[dict], None]


class TuningStoreError(Exception):
    """A tuning store that cannot be used or is not valid; one line."""


def is_tuning_store(path: Path | str) -> bool:
    return Path(path).is_dir() and not Path(path).is_symlink() and (Path(path) / HEADER).is_file()


@dataclass(frozen=True)
class Search:  # what a record is checked against: the store's identity and the search it holds
    tuning_id: str
    digest: str  # sha256 of the simulation code's fingerprint and the search's definition
    methods: tuple[str, ...]
    seeds: tuple[int, ...]
    check_seeds: tuple[int, ...]
    heldout_seeds: tuple[int, ...]
    most: int  # the largest budget a run of the search asked for


def search_of(header: dict) -> Search:
    definition = json.loads(header["definition_json"])
    return Search(header["tuning_id"], hashlib.sha256(f"{header['fingerprint']}\0{header['definition_json']}".encode())
                  .hexdigest(), tuple(definition["methods"]), tuple(definition["seeds"]),
                  tuple(definition["check_seeds"]), tuple(definition["heldout_seeds"]),
                  max([s["trials"] for s in header["sessions"] if _is_int(s.get("trials"))] or [0]))


def read_header(path: Path | str) -> dict:
    """The checked header of the tuning store ``path``; TuningStoreError (one line) naming what is wrong."""
    try:
        header = records.read_json(Path(path) / HEADER, MAX_BYTES)
        records.check_fields(header, HEADER_FIELDS, "a tuning header")
        if (header["schema"], header["schema_version"]) != (SCHEMA_NAME, SCHEMA_VERSION):
            raise RecordError(f"schema {header['schema']!s:.40} {header['schema_version']!s:.20}; this ilcforce "
                              f"reads {SCHEMA_NAME} {SCHEMA_VERSION}")
        definition = json.loads(header["definition_json"])
        if not (isinstance(header["sessions"], list) and all(isinstance(s, dict) for s in header["sessions"]) and
                all(isinstance(m, str) for m in definition["methods"]) and
                all(map(_is_int, definition["seeds"] + definition["check_seeds"] + definition["heldout_seeds"]))):
            raise RecordError("its sessions or the search's methods or seeds are not what they must be")
    except (RecordError, ValueError, RecursionError, TypeError, KeyError) as error:
        raise TuningStoreError(f"{Path(path) / HEADER}: not a valid tuning header ({error})") from None
    return header


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def check_record(record, search: Search, name: tuple[str, str] | None = None, check: Check | None = None) -> None:
    """RecordError unless ``record`` is a sealed, whole trial of ``search`` (stored under the file
    name whose (method, number) is ``name``) that passes the search's own ``check``."""
    records.check_fields(record, RECORD_FIELDS, "a trial")
    if record["tuning"] != search.tuning_id:
        raise RecordError("it belongs to another tuning store (its tuning id is not this store's)")
    if record["search"] != search.digest:
        raise RecordError("it was computed for another search or by other simulation code")
    method, number = record["method"], record["number"]
    if method not in search.methods or not _is_int(number):
        raise RecordError(f"method {str(method)[:64]!r} is not one this tuning searches, or its number is no integer")
    if name is not None and (method, number) != (name[0], int(name[1])):
        raise RecordError(f"it holds {method} trial {number}, not the trial of its file name")
    if not 0 <= number < search.most:
        raise RecordError(f"trial {number} is beyond every budget a run of this tuning asked for ({search.most})")
    seeds, checks = record["seeds"], record["checks"]
    unrun = record["state"] == FAILED and seeds == [] and checks == []  # gains refused before any cell ran
    axes = None
    if not unrun:
        axes = _check_entries(seeds, search.seeds, seed_keys, "seeds")
        _check_entries(checks, search.check_seeds, check_keys, "check seeds", axes)
    for entry in seeds:
        for key in ("value", "chattering"):
            if entry[key] is not None and not _is_number(entry[key]):
                raise RecordError(f"seed {entry['seed']}: {key} {str(entry[key])[:30]} is not a finite number")
    if record["state"] == COMPLETE:
        for key in ("value", "chattering"):
            values = [e[key] for e in seeds]
            if not _is_number(record[key]) or None in values or record[key] != statistics.median(values):
                raise RecordError(f"{key} {str(record[key])[:30]} is not the median of its seeds' values")
    elif record["state"] != FAILED or record["value"] is not None or record["chattering"] is not None:
        raise RecordError(f"state {str(record['state'])[:20]!r} with value {str(record['value'])[:30]}")
    if not isinstance(record["feasible"], bool) or record["feasible"] and record["state"] != COMPLETE:
        raise RecordError("feasible is not true or false, or true for a failed trial")
    cap = record["cap"]
    widths = [len(axes)] if axes is not None else [len(a) for a in AXES]  # unrun: the cap of the search's task
    if cap is not None and not (isinstance(cap, list) and len(cap) in widths and
                                all(_is_number(c) and c > 0 for c in cap)):
        raise RecordError(f"its cap is not {' or '.join(_WORDS[w] for w in widths)} positive numbers"
                          + (f" (one per task axis {', '.join(axes)})" if axes is not None and axes != AXES[0] else ""))
    params = record["params"]
    if not isinstance(params, dict) or not all(map(_is_number, params.values())) or (number == 0) != (params == {}):
        raise RecordError("params is not a table of finite numbers (empty for trial 0 alone, the experiment's gains)")
    if not (isinstance(record["gains"], dict) and isinstance(record["message"], str) and
            _is_number(record["elapsed"]) and record["elapsed"] >= 0 and isinstance(record["in_sampler"], bool)):
        raise RecordError("gains, message, elapsed or in_sampler is not of its kind")
    if check is not None:
        check(record)


_WORDS = {2: "two", 3: "three"}


def entry_axes(entry: dict, keys: Callable[[tuple[str, ...]], tuple[str, ...]]) -> tuple[str, ...] | None:
    """The task axes whose fields (``keys``: :func:`seed_keys`, :func:`check_keys` or :func:`heldout_keys`)
    ``entry`` holds, and no others but a ``message``; None when it holds no task's."""
    return next((axes for axes in AXES if set(keys(axes)) <= set(entry) <= {*keys(axes), "message"}), None)


def record_axes(record: dict) -> tuple[str, ...] | None:
    """The task axes of a checked trial (of its scoring seeds) or held-out evaluation (of its held-out seeds);
    None for a trial whose gains were refused before any cell ran."""
    keys = heldout_keys if "checks" not in record else seed_keys
    return entry_axes(record["seeds"][0], keys) if record["seeds"] else None


def _check_entries(entries, seeds: tuple[int, ...], keys: Callable[[tuple[str, ...]], tuple[str, ...]], what: str,
                   axes: tuple[str, ...] | None = None) -> tuple[str, ...] | None:
    """The task axes of ``entries`` (one per seed of ``seeds``), each holding the ``keys`` of the same task's
    axes (those of ``axes`` when given: another part of the record set them); RecordError otherwise."""
    if not isinstance(entries, list) or [e.get("seed") if isinstance(e, dict) and _is_int(e.get("seed")) else None
                                         for e in entries] != list(seeds):
        raise RecordError(f"its {what} are not the tuning's {list(seeds)[:10]}")
    for entry in entries:
        found = entry_axes(entry, keys)
        if found is None:
            raise RecordError(f"{what[:-1]} {entry['seed']}: its fields are not "
                              f"{' or '.join(', '.join(keys(a)) for a in ([axes] if axes else AXES))}")
        if axes is not None and found != axes:
            raise RecordError(f"{what[:-1]} {entry['seed']}: its fields are of the task axes {', '.join(found)}, "
                              f"the record's others of {', '.join(axes)}; a record is of one task")
        axes = found
    return axes


def check_heldout(record, search: Search, trials: dict, name: tuple[str, str] | None = None) -> None:
    """RecordError unless ``record`` is a sealed held-out evaluation of a stored trial of ``search``
    (``trials``: method -> {number: record}) with the gains of that trial, on the held-out seeds."""
    records.check_fields(record, HELDOUT_FIELDS, "a held-out evaluation")
    if (record["tuning"], record["search"]) != (search.tuning_id, search.digest):
        raise RecordError("it belongs to another tuning store or search")
    method, number = record["method"], record["number"]
    if name is not None and (method, number) != (name[0], int(name[1])):
        raise RecordError(f"it holds {str(method)[:64]} trial {str(number)[:10]}, not the trial of its file name")
    trial = trials.get(method, {}).get(number) if _is_int(number) and isinstance(method, str) else None
    if trial is None or trial["gains"] != record["gains"]:
        raise RecordError(f"it evaluates {str(method)[:64]} trial {str(number)[:10]}, which is not stored with "
                          "these gains")
    axes = _check_entries(record["seeds"], search.heldout_seeds, heldout_keys, "held-out seeds", record_axes(trial))
    for entry in record["seeds"]:
        if not all(entry[k] is None or _is_number(entry[k]) for k in ("e_p", "e_f", *(f"h_{a}" for a in axes))):
            raise RecordError(f"held-out seed {entry['seed']}: a norm is not a finite number")


def scan_heldout(path: Path, search: Search, trials: dict) -> tuple[dict, list]:
    """((method, number) -> held-out record that passes, [(file, why)] refused) in ``<path>/heldout/``."""
    found, refused = {}, []
    folder = Path(path) / HELDOUT
    for item in sorted(folder.iterdir()) if folder.is_dir() and not folder.is_symlink() else []:
        if (match := _TRIAL_FILE.fullmatch(item.name)) is not None:
            try:
                record = records.read_json(item, MAX_BYTES)
                check_heldout(record, search, trials, (match["method"], match["number"]))
                found[(record["method"], record["number"])] = record
            except RecordError as error:
                refused.append((item, str(error)))
    return found, refused


def scan(path: Path, search: Search, check: Check | None = None) -> tuple[dict, list]:
    """(method -> {number: record} of the records that pass, [(file, why)] of those refused) in
    ``<path>/trials/``: files not named as a trial (hidden ones included) are never opened."""
    trials: dict[str, dict[int, dict]] = {}
    refused = []
    folder = Path(path) / TRIALS
    for item in sorted(folder.iterdir()) if folder.is_dir() and not folder.is_symlink() else []:
        if (match := _TRIAL_FILE.fullmatch(item.name)) is not None:
            try:
                record = records.read_json(item, MAX_BYTES)
                check_record(record, search, (match["method"], match["number"]), check)
                trials.setdefault(record["method"], {})[record["number"]] = record
            except RecordError as error:
                refused.append((item, str(error)))
    return trials, refused


def read_trials(path: Path | str, check: Check | None) -> dict[str, dict[int, dict]]:
    """Every trial record that passes its checks and the search's own ``check`` (None: the store's
    checks alone; :func:`ilcforce.tune.runner.read_trials` gives the search's): method -> {number: record}."""
    return scan(Path(path), search_of(read_header(path)), check)[0]


def read_heldout(path: Path | str, check: Check | None) -> dict[tuple[str, int], dict]:
    """Every held-out evaluation that passes its checks: (method, number) -> record."""
    search = search_of(read_header(path))
    return scan_heldout(Path(path), search, scan(Path(path), search, check)[0])[0]


def validate_tuning(path: Path | str, check: Check | None) -> dict:
    """Check a tuning store; returns {name, methods: {method: (trials, failed, best value)}}.

    Raises :class:`TuningStoreError` (one line) for a damaged header, any record refused (named,
    with why), or a gap in a method's trial numbers (the next ``ilcforce tune`` runs it again)."""
    path = Path(path)
    header = read_header(path)
    search = search_of(header)
    trials, refused = scan(path, search, check)
    refused += scan_heldout(path, search, trials)[1]
    if refused:
        item, why = refused[0]
        more = f" (and {len(refused) - 1} more refused records)" if len(refused) > 1 else ""
        raise TuningStoreError(f"{item}: refused ({why}){more}; the next `ilcforce tune` moves it aside and runs "
                               "its trial again")
    tuned, digests = path / TUNED, [s["tuned_sha256"] for s in header["sessions"] if "tuned_sha256" in s]
    if os.path.lexists(tuned):
        why = _sealed_tuned(tuned, digests)[1]
        if why is not None:
            advice = "move it away" if os.path.isdir(tuned) and not os.path.islink(tuned) else \
                "rerun `ilcforce tune` to write it again"
            raise TuningStoreError(f"{tuned}: not the tuned file the last run wrote ({why}); {advice}")
    summary = {}
    for method, stored in trials.items():
        numbers = sorted(stored)
        if numbers != list(range(len(numbers))):
            gap = next(i for i, n in enumerate(numbers) if n != i)
            raise TuningStoreError(f"{path}: {method}'s trial {gap} is missing (the next `ilcforce tune` runs it again)")
        values = [r["value"] for r in stored.values() if r["state"] == COMPLETE and r["feasible"]]
        summary[method] = (len(stored), sum(not r["feasible"] for r in stored.values()), min(values, default=None))
    return {"name": header["name"], "methods": summary}


def _sealed_tuned(tuned: Path, digests: list[str]) -> tuple[bytes | None, str | None]:
    """(the bytes of the store's ``tuned.toml``, None) if it is the one its last writer sealed, else
    (None, why not). Read by the one safe open, never through a link: a link there may lead out of
    the store, and a FIFO or /dev/zero would hold or exhaust the reader."""
    try:
        data = read_regular(tuned, MAX_TOML_BYTES, follow_links=False)
    except UnreadableFile as exc:
        return None, f"it {exc}"
    if not digests or hashlib.sha256(data).hexdigest() != digests[-1]:
        return None, "its sha256 differs"
    return data, None


class TuningStore:
    """The writer of one tuning store (the driver is the only writer). Opening it locks it, checks a
    stored tuning against ``header`` (same definition and simulation code, unless ``overwrite``),
    moves refused records aside (:attr:`quarantined`, one line each) and reads the trials that
    passed (:attr:`trials`, per method a dict number -> record)."""

    def __init__(self, path: Path, header: dict, session: dict, *, overwrite: bool = False,
                 check: Check | None = None) -> None:
        self.path, self.check, self._lock = Path(path), check, None
        if self.path.is_symlink() or (self.path.exists() and not self.path.is_dir()):
            raise TuningStoreError(f"{self.path}: exists and is not a directory; refusing to touch it")
        if self.path.exists() and any(self.path.iterdir()) and not (self.path / HEADER).is_file():
            raise TuningStoreError(f"{self.path}: exists and is not an ilcforce tuning store; move it away")
        for folder in (TRIALS, HELDOUT):  # never written through a link, never mistaken for a folder
            if (self.path / folder).is_symlink() or (self.path / folder).exists() and not (self.path / folder).is_dir():
                raise TuningStoreError(f"{self.path / folder}: not a folder of this store (a link or a file); move it away")
        if (self.path / TUNED).is_dir() and not (self.path / TUNED).is_symlink():  # anything else there is replaced
            raise TuningStoreError(f"{self.path / TUNED}: a folder where the store keeps its tuned file; move it away")
        self.created = not self.path.exists()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            self._lock = acquire_writer_lock(self.path, f"{self.path}: another `ilcforce tune` is writing this tuning store")
            self._open(header, session, overwrite)
        except (OSError, StoreError) as exc:
            self.close()
            raise TuningStoreError(str(exc) if isinstance(exc, StoreError) else
                                   f"{self.path}: cannot open the tuning store ({exc.strerror or exc})") from None
        except BaseException:
            self.close()
            raise

    def _open(self, header: dict, session: dict, overwrite: bool) -> None:
        stored = None
        if (self.path / HEADER).exists():
            try:
                stored = read_header(self.path)
            except TuningStoreError as error:
                if not overwrite:
                    raise TuningStoreError(f"{error}; pass --overwrite to start the tuning over") from None
            for key, why in (("definition_json", "its tuning file defines another search (experiment, methods, seeds, "
                                                 "ranges or objective)"),
                             ("fingerprint", "its trials were computed by different simulation code")):
                if stored is not None and stored[key] != header[key] and not overwrite:
                    raise TuningStoreError(f"{self.path}: {why}; pass --overwrite to start the tuning over")
        for item in dead_copies_in(self.path) + dead_copies_in(self.path / TRIALS) + dead_copies_in(self.path / HELDOUT):
            item.unlink(missing_ok=True)
        if stored is None or overwrite:
            for folder in (TRIALS, HELDOUT):
                if (self.path / folder).exists():
                    shutil.rmtree(self.path / folder)
            (self.path / TUNED).unlink(missing_ok=True)
            stored = {**header, "tuning_id": uuid.uuid4().hex, "sessions": []}
        # the tuning file as last run (its definition, the budget included, is the stored one)
        self.header = {**stored, "tuning_toml": header["tuning_toml"], "sessions": [*stored["sessions"], session]}
        self.save_header()
        self.header = read_header(self.path)
        (self.path / TRIALS).mkdir(exist_ok=True)
        self.search = search_of(self.header)
        self.trials, refused = scan(self.path, self.search, self.check)
        self.heldout, refused_heldout = scan_heldout(self.path, self.search, self.trials)
        self.quarantined = [f"{item}: refused ({why}); moved to {records.quarantine(item)}, it runs again"
                            for item, why in refused + refused_heldout]
        self.committed = 0

    def commit(self, record: dict) -> None:
        """Store one finished trial (whole or not at all; never over a stored one)."""
        record = self._write(TRIALS, record, lambda r: check_record(r, self.search, None, self.check), "the trial")
        self.trials.setdefault(record["method"], {})[record["number"]] = record

    def commit_heldout(self, record: dict) -> None:
        """Store one held-out evaluation (whole or not at all; never over a stored one)."""
        record = self._write(HELDOUT, record, lambda r: check_heldout(r, self.search, self.trials),
                             "the held-out evaluation")
        self.heldout[(record["method"], record["number"])] = record

    def _write(self, folder: str, record: dict, check: Callable[[dict], None], what: str) -> dict:
        """Seal ``record``, check it as a reader would, and write it under ``folder`` by its method and
        number; returns the sealed record."""
        record = records.seal({**record, "tuning": self.search.tuning_id, "search": self.search.digest})
        target = self.path / folder / f"{record['method']}-{record['number']:05d}.json"
        try:  # never commit a record that a reader would refuse
            check(record)
        except RecordError as exc:
            raise TuningStoreError(f"{target}: refusing to store {what} ({exc})") from None
        if not check_writer_lock(self._lock):
            raise TuningStoreError(f"{self.path}: no longer the folder this tuning locked; stopping")
        try:
            target.parent.mkdir(exist_ok=True)
            records.atomic_write(target, json.dumps(record).encode(), replace=False)
        except FileExistsError:
            raise TuningStoreError(f"{target}: already stored; refusing to overwrite it") from None
        except OSError as exc:
            raise TuningStoreError(f"{target}: cannot write ({exc.strerror or exc}); every record stored before "
                                   "is kept") from None
        self.committed += 1
        return record

    def tuned_text(self) -> str | None:
        """The tuned file this store holds, if it is the one its last writer sealed (else None)."""
        digests = [s["tuned_sha256"] for s in self.header["sessions"] if "tuned_sha256" in s]
        data = _sealed_tuned(self.path / TUNED, digests)[0]  # None: a run that ships gains writes it again,
        return data.decode() if data is not None else None   # replacing whatever is at the name

    def save_header(self) -> None:
        records.atomic_write(self.path / HEADER, json.dumps(records.seal(self.header)).encode())

    def write_tuned(self, text: str) -> Path:
        """Write ``tuned.toml`` and seal it: its sha256 goes into this run's session."""
        records.atomic_write(self.path / TUNED, text.encode())
        self.header["sessions"][-1]["tuned_sha256"] = hashlib.sha256(text.encode()).hexdigest()
        self.save_header()
        return self.path / TUNED

    def discard_if_unused(self) -> None:
        """Remove a store this run made and stored no trial in (e.g. the scheduler was unreachable)."""
        if self.created and not self.committed and self._lock is not None:
            shutil.rmtree(self.path, ignore_errors=True)
        self.close()

    def close(self) -> None:
        if self._lock is not None:
            os.close(self._lock)
            self._lock = None
