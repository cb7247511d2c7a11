"""Atomic commits of one store file.

* A new file (a fresh run or study, or ``--overwrite``) is written beside the store as
  ``<store>.tmp``, fsynced and renamed over it: until that rename the old file stays as it was.
* Every later commit changes the store in place under an undo journal
  (:mod:`ilcforce.store.journal`), holding the store's exclusive lock (readers hold it shared).
  Its cost is what the commit writes, independent of the file's size, in every
  ``HDF5_USE_FILE_LOCKING`` mode, and the disk holds the store plus one commit's journal.
* In place is used only on a file that is private to this run: a regular file with one name
  (``st_nlink == 1``). A store reached through a symbolic link, or with other hard links (a
  ``cp -al`` backup), is copied once to ``<store>.tmp``, changed there and renamed over the name
  the writer was given: the other names keep the old data. The same happens when a reader keeps
  the file locked for longer than :data:`INPLACE_LOCK_WAIT` (it keeps its own unchanged file),
  and for every commit to a study store (:func:`replace`).
"""

from __future__ import annotations

import fcntl
import os
import stat
from collections.abc import Callable
from pathlib import Path

import h5py

from ilcforce import stops
from ilcforce.store import journal
from ilcforce.store.safeio import (StoreError, flock_with_timeout, journal_path, one_line, os_reason,
                                   READ_LOCK_TIMEOUT, tmp_path)
from ilcforce.store.schema import LIBVER

#: How long a commit waits for readers before copying instead of writing in place, s.
INPLACE_LOCK_WAIT = 1.0

Change = Callable[[h5py.File], None]


def _remove_tmp(tmp: Path) -> None:
    try:
        if stat.S_ISREG(os.lstat(tmp).st_mode):
            os.unlink(tmp)
    except FileNotFoundError:
        pass


def _open_tmp(tmp: Path) -> int:
    _remove_tmp(tmp)
    return os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC, 0o644)


def _fail(path: Path, error: BaseException) -> StoreError:
    if isinstance(error, OSError) and error.strerror:
        reason = error.strerror
    else:
        reason = one_line(error)
    return StoreError(f"{path}: cannot commit ({reason}); the store keeps its last committed state")


def _apply(stream: journal.JournaledFile, mode: str, change: Change) -> None:
    """Open ``stream`` with h5py, apply ``change``, close; a write that failed inside HDF5 (where
    h5py may swallow it) is raised here."""
    handle = h5py.File(stream, mode, libver=LIBVER) if mode == "w" else h5py.File(stream, mode)
    try:
        change(handle)
    finally:
        handle.close()
    if stream.failed is not None:
        raise stream.failed


def _abandon(path: Path, tmp: Path, stream, error: BaseException) -> None:
    """A commit that failed: mark the stream failed, drop the temporary file, and turn a file
    problem into a one-line StoreError (anything else propagates unchanged)."""
    if stream is not None:
        stream.failed = stream.failed or error
    _remove_tmp(tmp)
    if isinstance(error, (OSError, RuntimeError, ValueError)):
        raise _fail(path, error) from None


def create(path: Path, build: Change) -> None:
    """Write a new store with ``build`` and rename it over ``path`` (atomic). A stop signal during
    it takes effect when it has ended (:mod:`ilcforce.stops`), as for :func:`update`."""
    with stops.critical():
        _create(path, build)


def _create(path: Path, build: Change) -> None:
    tmp = tmp_path(path)
    fd = -1
    stream = None
    try:
        fd = _open_tmp(tmp)
        stream = journal.JournaledFile(fd, None, 0)
        _apply(stream, "w", build)
        os.fsync(fd)
        os.replace(tmp, path)
    except BaseException as error:
        _abandon(path, tmp, stream, error)
        raise
    finally:
        if fd >= 0:
            os.close(fd)


def update(path: Path, change: Change) -> None:
    """Apply ``change`` to the store at ``path`` atomically (in place when the file is private).

    A second Ctrl-C raised inside HDF5's write-back of an object h5py releases is swallowed by
    h5py, and the commit would end "normally" with writes missing: stop signals that the CLI's
    handlers would raise wait until the commit has ended (:mod:`ilcforce.stops`)."""
    with stops.critical():
        _update(path, change)


def replace(path: Path, change: Change) -> None:
    """Apply ``change`` to a copy of the store at ``path`` and rename it over ``path`` (never in
    place: a study store, whose ``<store>.journal`` is its folder of cell records)."""
    with stops.critical():
        _copy_update(path, change)


def _update(path: Path, change: Change) -> None:
    try:
        info = os.lstat(path)
    except OSError as error:
        raise StoreError(f"{path}: cannot commit ({os_reason(error)})") from None
    if not stat.S_ISREG(info.st_mode) or info.st_nlink != 1:
        _copy_update(path, change)
        return
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as error:
        raise StoreError(f"{path}: cannot open for writing ({os_reason(error)})") from None
    try:
        if not flock_with_timeout(fd, fcntl.LOCK_EX, INPLACE_LOCK_WAIT):
            os.close(fd)
            fd = -1
            _copy_update(path, change)
            return
        now = os.fstat(fd)
        named = os.lstat(path)
        if now.st_nlink != 1 or (now.st_dev, now.st_ino) != (named.st_dev, named.st_ino):
            os.close(fd)
            fd = -1
            _copy_update(path, change)
            return
        _update_in_place(path, fd, now.st_size, change)
    finally:
        if fd >= 0:
            os.close(fd)


def _update_in_place(path: Path, fd: int, size: int, change: Change) -> None:
    jpath = journal_path(path)
    try:
        jfd = journal.start(jpath, size, fd)
    except OSError as error:
        raise _fail(path, error) from None
    stream = journal.JournaledFile(fd, jfd, size)
    try:
        _apply(stream, "r+", change)
    except BaseException as error:
        stream.failed = stream.failed or error  # HDF5 may still flush when its objects are freed
        os.close(jfd)
        try:
            journal.roll_back(fd, jpath)
        except OSError:  # the journal stays: the next reader or writer undoes the commit
            pass
        if isinstance(error, (OSError, RuntimeError, ValueError)):
            raise _fail(path, error) from None
        raise
    os.close(jfd)
    os.unlink(jpath)  # the commit point


def _copy_update(path: Path, change: Change) -> None:
    """Copy the store (read under its shared lock) to ``<store>.tmp``, change, rename over ``path``."""
    tmp = tmp_path(path)
    fd = src = -1
    stream = None
    try:
        src = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        if not flock_with_timeout(src, fcntl.LOCK_SH, READ_LOCK_TIMEOUT):
            raise StoreError(f"{path}: another process kept it locked for more than {READ_LOCK_TIMEOUT:g} s")
        fd = _open_tmp(tmp)
        size = os.fstat(src).st_size
        copied = 0
        while copied < size:
            n = os.copy_file_range(src, fd, size - copied, copied, copied)
            if n == 0:
                break
            copied += n
        stream = journal.JournaledFile(fd, None, size)
        _apply(stream, "r+", change)
        os.fsync(fd)
        os.replace(tmp, path)
    except StoreError:
        _remove_tmp(tmp)
        raise
    except BaseException as error:
        _abandon(path, tmp, stream, error)
        raise
    finally:
        for f in (fd, src):
            if f >= 0:
                os.close(f)
