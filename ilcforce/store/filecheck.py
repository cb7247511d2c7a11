"""Checks before HDF5 touches a file, and the store's one-line error: the bottom of the store package.

* :class:`StoreError` and its subclasses: one line naming the file and the problem.
* What a path is before it is opened (a regular, non-empty file; an HDF5 signature), never
  blocking on a FIFO.
* Bounded time on damaged files: before h5py opens a file, :func:`probe` walks its structure in a
  forked child with a time limit (HDF5 can loop forever on a damaged block, and then ignores
  Ctrl-C). Data damage is caught by the checksums on read.
* A file's names are its own data: :func:`check_links` refuses a soft or external link (the writers
  make none; a reader would follow one elsewhere in the file or into another file).

Both the run store's locking layer (:mod:`.safeio`) and the study store's reader
(:mod:`.study_read`) build on this module; it imports neither.
"""

from __future__ import annotations

import os
import select
import signal
import stat
from pathlib import Path

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


def _walk(path: Path, image: bytes | None = None) -> None:
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

    opened = h5py.File(h5py.h5f.open_file_image(image)) if image is not None else h5py.File(path, "r", locking=False)
    with opened as handle:
        for key in handle.attrs:
            handle.attrs[key]
        h5py.h5o.visit(handle.id, visit, info=True)
        for name in chunked:
            dataset = handle[name]
            if dataset.chunks is not None and dataset.size <= 1 << 16:
                dataset[()]


def probe(path: Path, fd: int | None, timeout: float = PROBE_TIMEOUT, *, image: bytes | None = None,
          key: tuple[int, int, int, int] | None = None) -> None:
    """Walk the file's structure in a forked child with a time limit; StoreError if it fails.

    HDF5 can loop forever on a damaged metadata block (a 4 KB block of zeros early in a file hangs
    reading the root attributes, even with checksummed metadata: measured), and a hung HDF5 call
    ignores Ctrl-C. The child inherits the imported h5py, so the check costs a fork and one walk
    of the metadata (no data), once per version of the file (keyed by inode, size and mtime).
    """
    if key is None:
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
            _walk(path, image)
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


def file_identity(path: Path) -> Path:
    """The name the writers of ``path`` lock: its real path (symbolic links resolved), so that two
    names of one file take one lock. (Hard links need no lock in common: a commit to a file with
    other names copies it and renames the copy over its own name, see :mod:`.commit`.)"""
    return Path(os.path.realpath(path))


def writers_lock(path: Path) -> Path:
    """The lock file every writer of ``path``, under any of its names, takes: beside its real path."""
    return file_identity(Path(path)).with_name(file_identity(Path(path)).name + ".lock")


def check_links(handle, path: Path) -> None:
    """StoreError (one line) if any name in the file is a soft or external link: the writers make none, and
    a reader would follow one to another object or into another file (checked before anything is read)."""
    import h5py

    found: list[bytes] = []

    def visit(name: bytes, info) -> int | None:
        if info.type != h5py.h5l.TYPE_HARD:
            found.append(name)
            return 1  # stop the walk at the first
        return None

    handle.id.links.visit(visit, info=True)  # low level: no Python object per link (a 150-iteration store has 4,000)
    if found:
        name = found[0].decode("utf-8", "replace")
        link = handle.get(name, getlink=True)
        target = (f"{link.filename}:{link.path}" if isinstance(link, h5py.ExternalLink)
                  else str(getattr(link, "path", "")))
        kind = ("an external link" if isinstance(link, h5py.ExternalLink) else
                "a soft link" if isinstance(link, h5py.SoftLink) else "a user-defined link")
        raise StoreError(f"{path}: /{name[:60]} is {kind} (to {target[:80]}), not data of this store; a store "
                         "holds its own data only")
