"""Opening store files safely: errors, locks, interrupted commits and damaged files.

* :class:`StoreError` and its subclasses: one line naming the file and the problem.
* Locks. ``<store>.lock`` (flock, exclusive) is held by a writer for its whole run: a second
  writer is refused. The store file itself (flock on the inode, so every name of the file sees
  it) is locked shared by readers while they read and exclusive by a writer while it commits:
  a reader never sees half a commit, whatever ``HDF5_USE_FILE_LOCKING`` says. Lock files are
  opened with O_NOFOLLOW, never truncated, and written only when this process created them.
* Bounded time on damaged files: before h5py opens a file here, :func:`probe` walks its
  structure in a forked child with a time limit (HDF5 can loop forever on a damaged block, and
  then ignores Ctrl-C). Data damage is caught by the checksums on read.
"""

from __future__ import annotations

import errno
import fcntl
import os
import re
import select
import signal
import stat
import time
from contextlib import contextmanager
from collections.abc import Iterator
from pathlib import Path

from ilcforce.store import journal

#: How long a reader waits for a writer's commit to finish, s (a commit takes milliseconds).
READ_LOCK_TIMEOUT = 30.0
#: Time limit for walking a file's structure in a child process, s (a healthy store: milliseconds).
PROBE_TIMEOUT = 10.0

#: The first bytes of every HDF5 file (a store, ours or not).
HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"


class StoreError(Exception):
    """A problem with a store file. The message is one line naming the file and the problem."""

    def __init__(self, message: str) -> None:
        super().__init__(one_line(message))


class StoreLockedError(StoreError):
    """Another process (or another open writer) is writing the same store."""


class StoreExistsError(StoreError):
    """The store exists and neither overwrite nor resume was asked for."""


def one_line(text: object) -> str:
    """``text`` as one line (newlines and runs of blanks collapsed)."""
    return " ".join(str(text).split())


def os_reason(error: OSError) -> str:
    return error.strerror or one_line(error)


def journal_path(path: Path) -> Path:
    return path.with_name(path.name + ".journal")


def lock_path(path: Path) -> Path:
    return path.with_name(path.name + ".lock")


def tmp_path(path: Path) -> Path:
    """This process's temporary copy of the store at ``path``: hidden and named by its PID, a name
    no store may have (:func:`is_temporary_name`), so removing it can never remove a store."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


_TEMPORARY = re.compile(r"\.(.+)\.tmp-([0-9]{1,10})")


def is_temporary_name(name: str) -> bool:
    """Whether ``name`` is one ilcforce gives its temporary copies (``.<name>.tmp-<pid>``)."""
    return _TEMPORARY.fullmatch(name) is not None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def dead_writers_copies(path: Path) -> list[Path]:
    """The temporary copies of the store at ``path`` (exactly ``.<name>.tmp-<pid>``, regular files)
    whose writer process is gone: left by a kill -9. The caller holds the store's writer lock, so
    no live writer of this store is making one; a copy of a live process is never listed."""
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    found = []
    for name in names:
        match = _TEMPORARY.fullmatch(name)
        if match is None or match.group(1) != path.name:
            continue
        pid = int(match.group(2))
        if pid == os.getpid() or _alive(pid):
            continue
        try:
            if stat.S_ISREG(os.lstat(path.parent / name).st_mode):
                found.append(path.parent / name)
        except OSError:
            pass
    return found


def file_identity(path: Path) -> Path:
    """The name the writers of ``path`` lock: its real path (symbolic links resolved), so that two
    names of one file take one lock. (Hard links need no lock in common: a commit to a file with
    other names copies it and renames the copy over its own name, see :mod:`.commit`.)"""
    return Path(os.path.realpath(path))


def companion_of(path: Path) -> str | None:
    """What ``path`` is if it is a file ilcforce keeps beside a store (its writers' lock file, a
    study's journal folder), else None."""
    for suffix, what in ((".lock", "the writers' lock file of {}"), (".journal", "the journal of {}")):
        if path.name.endswith(".h5" + suffix) and not path.is_symlink():
            store_path = path.with_name(path.name[:-len(suffix)])
            kind_ok = path.is_file() if suffix == ".lock" else path.exists()
            if kind_ok:
                return what.format(store_path) + ("" if store_path.exists() else ", which is not there")
    return None


# ----------------------------------------------------------------------------------------------
# the writer's lock file


def acquire_writer_lock(path: Path) -> int:
    """Take ``<real path>.lock`` exclusively (:func:`file_identity`: every name of the file
    reaches one lock); the fd (closing it releases the lock).

    Never follows a symlink, never truncates: the PID is written only into a file this call
    created. StoreLockedError if another writer holds it.
    """
    lock = lock_path(file_identity(path))
    flags = os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC
    created = False
    try:
        fd = os.open(lock, flags | os.O_CREAT | os.O_EXCL, 0o644)
        created = True
    except FileExistsError:
        try:
            fd = os.open(lock, flags)
        except OSError as error:
            if error.errno == errno.ELOOP:
                raise StoreError(f"{path}: lock file {lock} is a symbolic link; refusing to use it") from None
            raise StoreError(f"{path}: cannot open lock file {lock} ({os_reason(error)})") from None
    except OSError as error:
        raise StoreError(f"{path}: cannot create lock file {lock} ({os_reason(error)})") from None
    if not stat.S_ISREG(os.fstat(fd).st_mode):
        os.close(fd)
        raise StoreError(f"{path}: lock file {lock} is not a regular file; refusing to use it")
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as error:
        os.close(fd)
        if error.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
            raise StoreLockedError(
                f"{path} is being written by another ilcforce process; wait for it to finish or choose another --out"
            ) from None
        raise StoreError(f"{path}: cannot lock {lock} ({os_reason(error)})") from None
    if created:  # for humans looking at a stuck lock; only in a file we created
        try:
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass
    return fd


def writer_active(path: str | os.PathLike[str]) -> bool:
    """True while a writer holds ``<path>.lock`` (the flock dies with its process)."""
    try:
        fd = os.open(lock_path(file_identity(Path(path))), os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return False
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)
    return False


#: The longest pause between two tries of :func:`flock_with_timeout`, s. A writer whose store is
#: behind the simulation commits back to back, each commit taking the exclusive lock for about
#: 10 ms and leaving it free for well under 1 ms before the next: a reader retrying every 50 ms (as
#: it did) almost never hit a gap, and waited for the whole run (0.25-0.31 s against a 20-commit
#: burst, every time; a test's reader saw the run finished before it could interrupt it).
FLOCK_RETRY_MAX = 0.0005


def flock_with_timeout(fd: int, operation: int, timeout: float) -> bool:
    """flock(fd, operation) retried until ``timeout`` s; False if it never succeeded."""
    deadline = time.monotonic() + timeout
    delay = 0.0001
    while True:
        try:
            fcntl.flock(fd, operation | fcntl.LOCK_NB)
            return True
        except OSError as error:
            if error.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise
        if time.monotonic() >= deadline:
            return False
        time.sleep(delay)
        delay = min(delay * 2, FLOCK_RETRY_MAX)


# ----------------------------------------------------------------------------------------------
# checks before HDF5 touches a file


def check_regular_file(path: Path) -> os.stat_result:
    """stat of ``path`` (following links) if it is a non-empty regular file; StoreError otherwise."""
    try:
        info = os.stat(path)
    except FileNotFoundError:
        raise StoreError(f"{path}: no such file") from None
    except OSError as error:
        raise StoreError(f"{path}: cannot stat ({os_reason(error)})") from None
    if stat.S_ISDIR(info.st_mode):
        raise StoreError(f"{path}: is a directory, not a store file")
    if not stat.S_ISREG(info.st_mode):
        raise StoreError(f"{path}: not a regular file")
    if info.st_size == 0:
        raise StoreError(f"{path}: empty file (0 bytes), not a readable HDF5 file")
    return info


def superblock_version(fd: int) -> int | None:
    """The HDF5 superblock version of the file open as ``fd`` (signature at 0, 512, 1024, ...)."""
    size = os.fstat(fd).st_size
    offset = 0
    while offset + 9 <= size:
        head = os.pread(fd, 9, offset)
        if head[:8] == HDF5_SIGNATURE:
            return head[8]
        offset = 512 if offset == 0 else offset * 2
    return None


def is_hdf5_file(path: Path) -> bool:
    """Whether ``path`` is a regular file with an HDF5 signature (never blocks on a FIFO, never raises)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            return False
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    except OSError:
        return False
    try:
        return superblock_version(fd) is not None
    except OSError:
        return False
    finally:
        os.close(fd)


_probed: set[tuple[int, int, int, int]] = set()


def file_key(path: Path) -> tuple[int, int, int, int]:
    """(device, inode, size, mtime) of ``path``: one version of one file."""
    info = os.stat(path)
    return (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)


def mark_walked(key: tuple[int, int, int, int]) -> None:
    """Skip the probe for this version of a file: a store that a child process of ours has just
    written and closed (``ilcforce compare``'s workers send its :func:`file_key`); any later change
    to the file gives another key, which is probed as usual."""
    _probed.add(tuple(key))


def _walk(path: Path) -> None:
    """What HDF5 must parse to read a store: the root attributes (dense storage: where a zeroed
    block hung every command), every object header and link (``H5Ovisit`` with object info,
    which parses each header and its attribute info) and the chunk index of every chunked dataset
    (the small ``/reference``, ``/control_time`` and ``/metrics`` ones). No bulk data: the
    checksums catch damage there when it is read. About 50 ms for the paper's 20-iteration store
    on a loaded machine (measured); reading every attribute through h5py took 0.7 s."""
    import h5py

    chunked: list[bytes] = []

    def visit(name: bytes, info) -> None:
        if info.type == h5py.h5o.TYPE_DATASET:
            chunked.append(name)

    with h5py.File(path, "r", locking=False) as handle:
        for key in handle.attrs:
            handle.attrs[key]
        h5py.h5o.visit(handle.id, visit, info=True)
        for name in chunked:
            dataset = handle[name]
            if dataset.chunks is not None and dataset.size <= 1 << 16:
                dataset[()]


def probe(path: Path, fd: int, timeout: float = PROBE_TIMEOUT) -> None:
    """Walk the file's structure in a forked child with a time limit; StoreError if it fails.

    HDF5 can loop forever on a damaged metadata block (a 4 KB block of zeros early in a file hangs
    reading the root attributes, even with checksummed metadata: measured), and a hung HDF5 call
    ignores Ctrl-C. The child inherits the imported h5py, so the check costs a fork and one walk
    of the metadata (no data), once per version of the file (keyed by inode, size and mtime).
    """
    info = os.fstat(fd)
    key = (info.st_dev, info.st_ino, info.st_size, info.st_mtime_ns)
    if key in _probed:
        return
    import h5py  # noqa: F401  (imported before the fork, so the child does not pay for it)

    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child: walk, report one line, never return into the caller's code
        code = 1
        try:
            os.close(read_end)
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            _walk(path)
            os.write(write_end, b"ok")
            code = 0
        except BaseException as error:  # noqa: BLE001 - anything is a damaged file here
            try:
                os.write(write_end, one_line(f"{type(error).__name__}: {error}")[:300].encode("utf-8", "replace"))
            except BaseException:
                pass
        finally:
            os._exit(code)
    os.close(write_end)
    try:
        ready, _, _ = select.select([read_end], [], [], timeout)
        message = os.read(read_end, 400).decode("utf-8", "replace") if ready else None
        if message == "" and ready:  # the child closed without writing: wait for its status
            pass
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        os.close(read_end)
        raise
    os.close(read_end)
    if message is None:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise StoreError(f"{path}: not a readable HDF5 file (damaged: reading its structure did not finish in {timeout:g} s)")
    _, status = os.waitpid(pid, 0)
    if message != "ok":
        if not message:
            message = f"the reader died ({'signal ' + str(-os.waitstatus_to_exitcode(status))})"
        raise StoreError(f"{path}: not a readable HDF5 file (damaged: {message})")
    _probed.add(key)


# ----------------------------------------------------------------------------------------------
# opening for reading


@contextmanager
def read_locked(path: Path) -> Iterator[int]:
    """Hold a shared lock on the store file while reading it; finish an interrupted commit first.

    Yields the fd of the open file (so the reader reads the file it locked).
    """
    check_regular_file(path)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
    except OSError as error:
        raise StoreError(f"{path}: cannot open ({os_reason(error)})") from None
    try:
        if not flock_with_timeout(fd, fcntl.LOCK_SH, READ_LOCK_TIMEOUT):
            raise StoreError(f"{path}: a writer kept it locked for more than {READ_LOCK_TIMEOUT:g} s")
        if journal_path(path).exists():
            # We hold the shared lock, so no live writer is inside a commit: it was interrupted.
            fcntl.flock(fd, fcntl.LOCK_UN)
            repair_interrupted_commit(path)
            os.close(fd)
            fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
            if not flock_with_timeout(fd, fcntl.LOCK_SH, READ_LOCK_TIMEOUT):
                raise StoreError(f"{path}: a writer kept it locked for more than {READ_LOCK_TIMEOUT:g} s")
        yield fd
    finally:
        os.close(fd)


#: Why a study store is refused where a run store is expected (reading, --resume, --overwrite).
IS_A_STUDY_STORE = ("is a study store, not a run store; read it with ilcforce.study.read_study, "
                    "`ilcforce report` or `ilcforce export`")


def not_a_run_store(path: Path) -> str:
    """Why ``path``, whose journal is a folder (as a study store's is), is not read as a run store:
    a study store, or a damaged one whose journal folder may hold cells not yet merged (one line)."""
    from ilcforce.store.study_read import StudyStoreError, read_header

    try:
        read_header(Path(path))
    except StudyStoreError as error:
        return (f"{one_line(str(error))}; {journal_path(path)} is a study store's journal folder: keep it, "
                "it may hold cells not yet merged")
    return f"{path}: {IS_A_STUDY_STORE}"


def repair_interrupted_commit(path: Path) -> bool:
    """Undo the unfinished commit of a killed writer (exclusive lock on the store while doing so)."""
    if journal_path(path).is_dir():  # a study store keeps its journal as a folder (store/study.py)
        raise StoreError(not_a_run_store(path))
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError as error:
        raise StoreError(
            f"{path}: holds an unfinished commit of a killed writer and cannot be repaired here "
            f"({os_reason(error)}); run `ilcforce simulate --resume` with write access"
        ) from None
    try:
        if not flock_with_timeout(fd, fcntl.LOCK_EX, READ_LOCK_TIMEOUT):
            raise StoreError(f"{path}: a writer kept it locked for more than {READ_LOCK_TIMEOUT:g} s")
        try:
            return journal.roll_back(fd, journal_path(path))
        except journal.JournalError as error:
            raise StoreError(f"{path}: {error}; move it away to read the store") from None
        except OSError as error:
            raise StoreError(f"{path}: cannot undo an unfinished commit ({os_reason(error)})") from None
    finally:
        os.close(fd)
