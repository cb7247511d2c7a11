"""Sealed JSON records, the one implementation every store uses for what is not HDF5 (a study's
journal records, a tuning's header and trials) and for any small file written whole:
:func:`atomic_write` (whole or absent; never over a finished record with ``replace=False``),
:func:`seal` and :func:`check_fields` (sha256 over the canonical JSON of the parsed record: any change
of what a JSON reader reads; whitespace, key order and escapes are not part of it; no signature, hence
each store's checks of what a record claims), :func:`read_json` (bounded time on hostile files: size,
links, FIFOs, deep nesting; a key named twice in one object refused) and :func:`quarantine` (a refused
record kept aside).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from pathlib import Path


class RecordError(Exception):
    """Why a record is refused (one short phrase, without the file name)."""


def _canonical(body: dict) -> bytes:
    return json.dumps(body, sort_keys=True, separators=(",", ":"), allow_nan=True).encode()


def checksum(body: dict) -> str:
    """sha256 (hex) over ``body``'s canonical JSON, its ``checksum`` field left out."""
    return hashlib.sha256(_canonical({k: v for k, v in body.items() if k != "checksum"})).hexdigest()


def seal(body: dict) -> dict:
    """``body`` as plain JSON values (numpy scalars made Python numbers) with its ``checksum``."""
    body = json.loads(json.dumps(body))
    body["checksum"] = checksum(body)
    return body


def check_fields(record, fields: frozenset, what: str) -> None:
    """RecordError unless ``record`` is a JSON object whose ``checksum`` matches its content and whose
    fields are exactly ``fields``."""
    if not isinstance(record, dict):
        raise RecordError(f"a JSON {type(record).__name__}, not a record")
    if "checksum" not in record:
        raise RecordError("no checksum (written by an older ilcforce, or not a record)")
    try:
        expected = checksum(record)
    except (ValueError, TypeError, RecursionError):
        raise RecordError("cannot be checksummed") from None
    if record["checksum"] != expected:
        raise RecordError("its checksum does not match its content (changed after it was written)")
    if set(record) != fields:
        raise RecordError(f"fields differ from {what}'s ({', '.join(map(str, sorted(set(record) ^ fields)))[:120]})")


class DuplicateKey(ValueError):
    """A JSON object names a key twice (the key)."""


def _object(pairs: list) -> dict:
    """A JSON object, refused when it names a key twice: Python keeps the last value, other readers the
    first, and the seal (over the canonical form, one value a key) would not tell them apart."""
    found = dict(pairs)
    if len(found) != len(pairs):
        seen = set()
        raise DuplicateKey(next(k for k, _ in pairs if k in seen or seen.add(k)))
    return found


def read_json(item: Path, limit: int):
    """The JSON value in the regular file ``item`` (at most ``limit`` bytes); RecordError saying why not."""
    try:
        info = os.lstat(item)
    except OSError as error:
        raise RecordError(f"cannot be read ({error.strerror or error})") from None
    if stat.S_ISLNK(info.st_mode):
        raise RecordError("a symbolic link, not a record")
    if not stat.S_ISREG(info.st_mode):
        raise RecordError("not a regular file")
    if info.st_size > limit:
        raise RecordError(f"{info.st_size} bytes, more than a record holds ({limit})")
    try:
        fd = os.open(item, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
        try:
            if not stat.S_ISREG(os.fstat(fd).st_mode):  # replaced between lstat and open
                raise RecordError("not a regular file")
            data = os.read(fd, limit + 1)
        finally:
            os.close(fd)
    except OSError as error:
        raise RecordError(f"cannot be read ({error.strerror or error})") from None
    try:
        return json.loads(data.decode("utf-8"), object_pairs_hook=_object)
    except DuplicateKey as error:
        raise RecordError(f"the key {str(error)[:40]!r} appears twice in one object (readers disagree on which "
                          "counts)") from None
    except UnicodeDecodeError:
        raise RecordError("not UTF-8 text") from None
    except RecursionError:
        raise RecordError("JSON nested too deeply") from None
    except ValueError as error:
        raise RecordError(f"not JSON ({str(error).split(':')[0]})") from None


def atomic_write(path: Path, data: bytes, *, replace: bool = True) -> None:
    """Write ``data`` to ``path`` whole or not at all (OSError, nothing changed); with
    ``replace=False`` FileExistsError when ``path`` exists, even if it appears meanwhile."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
        try:
            view = memoryview(data)
            while view:
                view = view[os.write(fd, view):]
            os.fsync(fd)
        finally:
            os.close(fd)
        if replace:
            os.replace(tmp, path)
        else:
            os.link(tmp, path)  # fails when the name is taken: a finished record is never replaced
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
    fd = os.open(path.parent, os.O_RDONLY | os.O_CLOEXEC)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def quarantine(item: Path, folder_name: str = ".quarantine") -> Path:
    """Move the refused record ``item`` into ``<its folder>/.quarantine/`` (made if missing, never
    through a symbolic link), under a name not taken yet; returns where it went."""
    folder = item.parent / folder_name
    try:
        os.mkdir(folder, 0o755)
    except FileExistsError:
        if folder.is_symlink() or not folder.is_dir():
            raise OSError(f"{folder} is not a folder") from None
    target = folder / item.name
    n = 1
    while os.path.lexists(target):
        target = folder / f"{item.name}.{n}"
        n += 1
    os.rename(item, target)
    return target
