"""Atomic in-place commits: an undo journal under HDF5's file I/O.

A commit changes the store in place, so it costs what the iteration writes, not the file's size,
and needs no second copy on disk. HDF5 has no transactions, so every byte it overwrites below the
file's size at the start of the commit is first saved to ``<store>.journal``; bytes appended
past that size need no saving (undoing them is a truncation). The commit point is the removal of
the journal. A commit that did not finish (kill -9, a full disk, an exception) is undone by
:func:`roll_back`: the saved bytes are written back, the file is truncated to its old size, and
the journal is removed, giving back exactly the file of the last commit.

Journal format: a 32-byte header ``b"ILCJRNL2"`` + the store's size at the start, its device and
its inode (uint64 LE each); then records ``offset (uint64 LE) | length (uint64 LE) | old bytes``.
The device and inode tie the journal to its file: a journal beside another file of that name (a
backup moved into place after the crash) is refused, not applied, and so is one whose store is
now smaller than it was at the start (a commit only appends). A ``ILCJRNL1`` journal (16-byte
header, no identity; ilcforce before 2026-12-02) is applied under the size check only. A record is written (one
``write`` call) before the store bytes it covers are overwritten, so a torn last record covers
bytes that were never overwritten and is ignored.

The guarantee covers a killed process (the kernel keeps every completed write); against a power
cut, ``durable=True`` adds fsync calls at the two points that order the writes.
"""

from __future__ import annotations

import io
import os
import struct

MAGIC = b"ILCJRNL2"
_HEADER = struct.Struct("<8sQQQ")  # magic, size at the start, st_dev, st_ino of the store
_MAGIC_V1 = b"ILCJRNL1"
_HEADER_V1 = struct.Struct("<8sQ")
_RECORD = struct.Struct("<QQ")


class JournalError(Exception):
    """A journal that cannot be read back (not ours or damaged in its header)."""


class JournaledFile(io.RawIOBase):
    """A seekable binary file over ``fd`` whose overwrites of pre-existing bytes are journaled.

    Given to ``h5py.File`` as a file-like object (h5py's ``fileobj`` driver). With ``journal_fd``
    None, nothing is journaled (a new file, where every byte is appended).
    """

    def __init__(self, fd: int, journal_fd: int | None, base_size: int, durable: bool = False) -> None:
        super().__init__()
        self._fd = fd
        self._journal_fd = journal_fd
        self._base = base_size
        self._saved: list[tuple[int, int]] = []  # disjoint saved ranges [start, stop), sorted
        self._pos = 0
        self._durable = durable
        self.failed: BaseException | None = None  # the first failed write (the commit is then undone)

    # io protocol ------------------------------------------------------------------------

    def readable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if whence == os.SEEK_SET:
            self._pos = offset
        elif whence == os.SEEK_CUR:
            self._pos += offset
        else:
            self._pos = os.fstat(self._fd).st_size + offset
        return self._pos

    def tell(self) -> int:
        return self._pos

    def readinto(self, buffer) -> int:
        view = memoryview(buffer).cast("B")
        done = 0
        while done < len(view):
            chunk = os.preadv(self._fd, [view[done:]], self._pos + done)
            if chunk == 0:
                break
            done += chunk
        self._pos += done
        return done

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        start, stop = self._pos, self._pos + len(view)
        self._pos = stop
        if self.failed is not None:
            return len(view)
        try:
            self._save(start, min(stop, self._base))
            done = 0
            while done < len(view):
                done += os.pwrite(self._fd, view[done:], start + done)
        except BaseException as error:
            # HDF5 must never see a failed write: after one (a full disk, a file-size limit, a
            # KeyboardInterrupt raised here) its close can crash the process (measured: a
            # segmentation fault in H5Fclose). The failure is recorded, this and every later
            # write is dropped, and the caller undoes the commit from the journal once HDF5 has
            # closed the file, then raises the failure.
            self.failed = error
        return len(view)

    def truncate(self, size: int | None = None) -> int:
        size = self._pos if size is None else size
        if self.failed is not None:
            return size
        try:
            self._save(size, self._base)
            os.ftruncate(self._fd, size)
        except BaseException as error:
            self.failed = error
        return size

    def flush(self) -> None:
        pass

    # journal ------------------------------------------------------------------------------

    def _save(self, start: int, stop: int) -> None:
        """Journal the old bytes of [start, stop) not saved yet (no-op when nothing is below base)."""
        if self._journal_fd is None or start >= stop:
            return
        for gap_start, gap_stop in _gaps(self._saved, start, stop):
            old = os.pread(self._fd, gap_stop - gap_start, gap_start)
            record = _RECORD.pack(gap_start, len(old)) + old
            written = 0
            while written < len(record):
                written += os.write(self._journal_fd, record[written:])
            if self._durable:
                os.fsync(self._journal_fd)
            self._saved.append((gap_start, gap_start + len(old)))
        self._saved.sort()


def _gaps(saved: list[tuple[int, int]], start: int, stop: int) -> list[tuple[int, int]]:
    """Parts of [start, stop) not covered by the sorted disjoint ranges ``saved``."""
    gaps = []
    cursor = start
    for a, b in saved:
        if b <= cursor:
            continue
        if a >= stop:
            break
        if a > cursor:
            gaps.append((cursor, min(a, stop)))
        cursor = max(cursor, b)
        if cursor >= stop:
            break
    if cursor < stop:
        gaps.append((cursor, stop))
    return gaps


def start(journal_path: str | os.PathLike[str], base_size: int, store_fd: int) -> int:
    """Create the journal of the store open as ``store_fd`` (it must not exist; never through a
    symlink) and return its fd."""
    identity = os.fstat(store_fd)
    fd = os.open(journal_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)
    try:
        header = _HEADER.pack(MAGIC, base_size, identity.st_dev, identity.st_ino)
        if os.write(fd, header) != len(header):
            raise OSError("short write to the journal")
    except BaseException:
        os.close(fd)
        os.unlink(journal_path)
        raise
    return fd


def roll_back(store_fd: int, journal_path: str | os.PathLike[str]) -> bool:
    """Undo an unfinished commit recorded in ``journal_path`` on the store open as ``store_fd``.

    Returns False if there is no journal. The caller holds the store's exclusive lock. Idempotent:
    applying the same journal twice gives the same file. JournalError if the journal's header is
    not ours (the store is then left untouched).
    """
    try:
        fd = os.open(journal_path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except FileNotFoundError:
        return False
    try:
        data = b""
        while True:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            data += chunk
    finally:
        os.close(fd)
    base, offset = _check_header(data, journal_path, os.fstat(store_fd))
    if base is None:  # killed while writing the header: nothing in the store was changed yet
        os.unlink(journal_path)
        return True
    records = []
    while offset + _RECORD.size <= len(data):
        where, length = _RECORD.unpack_from(data, offset)
        body = data[offset + _RECORD.size: offset + _RECORD.size + length]
        if len(body) != length:
            break  # torn last record: its bytes were never overwritten
        records.append((where, body))
        offset += _RECORD.size + length
    for where, body in reversed(records):
        os.pwrite(store_fd, body, where)
    os.ftruncate(store_fd, base)
    os.fsync(store_fd)
    os.unlink(journal_path)
    return True


def _check_header(data: bytes, journal_path, store) -> tuple[int | None, int]:
    """(size at the start, where the records begin) of a journal that belongs to ``store`` (its
    ``os.stat_result``); (None, 0) for a header torn by a kill; JournalError for anything else,
    which is then left as it is, and the store untouched."""
    if len(data) < 8 and MAGIC.startswith(data):  # both versions begin "ILCJRNL"
        return None, 0
    for magic, header in ((MAGIC, _HEADER), (_MAGIC_V1, _HEADER_V1)):
        if data[:8] != magic:
            continue
        if len(data) < header.size:
            return None, 0
        base, *identity = header.unpack_from(data, 0)[1:]
        if identity and tuple(identity) != (store.st_dev, store.st_ino):
            raise JournalError(f"{journal_path} is the journal of another file, not of this store "
                               "(was the store replaced after a crash?)")
        if store.st_size < base:
            raise JournalError(f"{journal_path} does not fit this store (made when it had {base} bytes; "
                               f"it has {store.st_size})")
        return base, header.size
    raise JournalError(f"{journal_path} is not an ilcforce journal")
