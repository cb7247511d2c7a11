"""Opening store files safely: errors, locks, interrupted commits and damaged files.

* :class:`StoreError` and its subclasses: one line naming the file and the problem.
* Locks. ``<real path>.lock`` (flock, exclusive) is held by a writer for its whole run: a second
  writer is refused, through whichever name (:func:`file_identity`). The store file itself
  (flock on the inode, so every name of the file sees it) is locked shared by readers while they
  copy it (or, a very large one, read it: :data:`ilcforce.store.read.SNAPSHOT_BYTES`) and
  exclusive by a writer while it commits: a reader never sees half a commit, whatever
  ``HDF5_USE_FILE_LOCKING`` says. Lock files are
  opened with O_NOFOLLOW, never truncated, and written only when this process created them.
* Bounded time on damaged files: :mod:`.filecheck` (which also holds :class:`StoreError`), the
  layer below this one and below the study store's reader.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import re
import stat
import time
from contextlib import contextmanager
from collections.abc import Iterator
from pathlib import Path

from ilcforce.store import journal
from ilcforce.store.filecheck import file_identity, writers_lock  # noqa: F401 - the store's names for them
from ilcforce.store.filecheck import (  # noqa: F401 - re-exported: the store's modules import them from here
    HDF5_SIGNATURE, PROBE_TIMEOUT, StoreError, StoreExistsError, StoreLockedError, check_regular_file, file_key,
    is_hdf5_file, mark_walked, one_line, os_reason, probe, superblock_version,
)

#: How long a reader waits for a writer's commit to finish, s (a commit takes milliseconds).
READ_LOCK_TIMEOUT = 30.0


def journal_path(path: Path) -> Path:
    return path.with_name(path.name + ".journal")


def tmp_path(path: Path) -> Path:
    """This process's temporary copy of the store at ``path``: hidden and named by its PID, a name
    no store may have (:func:`is_temporary_name`), so removing it can never remove a store."""
    return path.with_name(f".{path.name}.tmp-{os.getpid()}")


_TEMPORARY = re.compile(r"\.(.+)\.tmp-([0-9]{1,10})")


def is_temporary_name(name: str) -> bool:
    """Whether ``name`` is one ilcforce gives its temporary copies (``.<name>.tmp-<pid>``)."""
    return _TEMPORARY.fullmatch(name) is not None


def process_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (another user's counts as alive): a writer's temporary file or a
    killed command's leftovers are removed only when their process is gone."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process: alive
        return True
    return True


def dead_copies_in(folder: Path, name: str | None = None) -> list[Path]:
    """The temporary copies in ``folder`` (exactly ``.<name>.tmp-<pid>``, regular files; of the store
    ``name`` only, if given) whose writer is gone: left by a kill -9. The caller holds the store's
    writer lock, so no live writer of it is making one; a copy of a live process is never listed."""
    try:
        matches = [m for m in map(_TEMPORARY.fullmatch, sorted(os.listdir(folder))) if m]
    except OSError:
        return []
    found = []
    for match in matches:
        pid, item = int(match.group(2)), Path(folder) / match.group(0)
        if (name is None or match.group(1) == name) and pid != os.getpid() and not process_alive(pid):
            with contextlib.suppress(OSError):
                found += [item] if stat.S_ISREG(os.lstat(item).st_mode) else []
    return found


def dead_writers_copies(path: Path) -> list[Path]:
    """:func:`dead_copies_in` of the store at ``path``."""
    return dead_copies_in(path.parent, path.name)


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


def acquire_writer_lock(path: Path, busy: str = "") -> int:
    """Lock the store at ``path`` for its one writer (StoreLockedError saying ``busy`` if taken); the
    fd, whose closing releases it. A folder (a tuning) is locked itself; a file through ``<real
    path>.lock``, never followed through a link, never truncated, checked after locking to still be
    the file of its name (docs/store-format.md: why, and what a deleted lock file does)."""
    busy = busy or (f"{path} is being written by another ilcforce process; wait for it to finish "
                    "or choose another --out")
    folder = os.path.isdir(path) and not os.path.islink(path)
    lock = Path(path) if folder else writers_lock(path)
    flags = os.O_RDONLY | os.O_DIRECTORY if folder else os.O_RDWR | os.O_NOFOLLOW
    for _attempt in range(100):
        created = False
        try:
            fd = os.open(lock, flags | os.O_CLOEXEC | (0 if folder else os.O_CREAT | os.O_EXCL), 0o644)
            created = not folder
        except FileExistsError:
            try:
                fd = os.open(lock, flags | os.O_CLOEXEC)
            except OSError as error:
                if error.errno == errno.ELOOP:
                    raise StoreError(f"{path}: lock file {lock} is a symbolic link; refusing to use it") from None
                raise StoreError(f"{path}: cannot open lock file {lock} ({os_reason(error)})") from None
        except OSError as error:
            raise StoreError(f"{path}: cannot create lock file {lock} ({os_reason(error)})") from None
        if not folder and not stat.S_ISREG(os.fstat(fd).st_mode):
            os.close(fd)
            raise StoreError(f"{path}: lock file {lock} is not a regular file; refusing to use it")
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as error:
            os.close(fd)
            if error.errno in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                raise StoreLockedError(busy) from None
            raise StoreError(f"{path}: cannot lock {lock} ({os_reason(error)})") from None
        with contextlib.suppress(FileNotFoundError):
            if os.path.samestat(os.fstat(fd), os.stat(lock, follow_symlinks=False)):
                break
        os.close(fd)  # deleted or replaced between open and flock: lock the file of the name now
    else:
        raise StoreError(f"{path}: its lock file {lock} keeps being replaced; refusing to write")
    if created:  # for humans looking at a stuck lock; only in a file we created
        try:
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError:
            pass
    return fd


def check_writer_lock(fd: int) -> bool:
    """Whether the writer's lock ``fd`` still has a name (False: its lock file was deleted or
    replaced, so a second writer may be in)."""
    return os.fstat(fd).st_nlink > 0


def writer_active(path: str | os.PathLike[str]) -> bool:
    """True while a writer holds ``<path>.lock`` (the flock dies with its process)."""
    try:
        fd = os.open(writers_lock(Path(path)), os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC | os.O_NONBLOCK)
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
