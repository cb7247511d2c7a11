"""The report folder: which folder a report may be written to, and how it gets there whole.

A report is built in a hidden sibling of its folder (``.<name>.partial-<pid>``) and moved into place
at the end in one step: the new folder is renamed over an absent or empty one, or exchanged with the
previous report (``renameat2(RENAME_EXCHANGE)`` on Linux), which is then removed. A report stopped
or failed midway (Ctrl-C, SIGTERM, a full disk, a kill) therefore leaves the previous report whole,
or no folder where there was none; a killed report's partial sibling is removed by the next report.

A report is written only to a folder that is absent, empty, or a report ilcforce wrote (it carries
:data:`~ilcforce.store.schema.REPORT_MARKER`; a report written before the marker existed is known by
its ``index.md``), because the whole folder is replaced: any other folder is refused, as ``export``
refuses an existing file, so no user's ``index.md`` or ``claims.csv`` is ever replaced unasked.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import shutil
import signal
import threading
from collections.abc import Iterator
from pathlib import Path

from ilcforce.store.safeio import process_alive
from ilcforce.store.schema import REPORT_MARKER
from ilcforce.stops import on_stop_signals

#: The first line of every report's index.md (ilcforce.report.index_page): how a report written
#: before :data:`REPORT_MARKER` existed is known.
INDEX_TITLE = "# ilcforce reports"
_PARTIAL = re.compile(r"^\.(?P<name>.+)\.(partial|previous)-(?P<pid>\d+)$")


class ReportFolderError(ValueError):
    """The report cannot be written to the folder asked for (a user's folder, or the results' own)."""


def is_report(folder: Path) -> bool:
    """Whether ``folder`` is a report ilcforce wrote (its marker, or an index.md of a report written
    before the marker)."""
    folder = Path(folder)
    if (folder / REPORT_MARKER).is_file():
        return True
    index = folder / "index.md"
    if index.is_symlink() or not index.is_file():  # a FIFO there would block the read below
        return False
    try:
        with index.open("rb") as handle:  # its first line only
            first = handle.read(len(INDEX_TITLE) + 1).decode("utf-8", "replace")
    except OSError:
        return False
    return first.rstrip("\r\n") == INDEX_TITLE


def check_target(out_dir: Path, results_dir: Path) -> Path:
    """The folder the report replaces (``out_dir``, a symlink followed); ReportFolderError, one line,
    when the report may not be written there: it is a file, it holds the results, or it is a folder
    of something else that is not empty."""
    out_dir = Path(out_dir)
    target = out_dir.resolve() if out_dir.is_symlink() else out_dir.absolute()
    if target.exists() and not target.is_dir():
        raise ReportFolderError(f"--out {out_dir} is a file, not a folder; the report is a folder (index.md and "
                                "one folder per experiment)")
    results = Path(results_dir).resolve()
    if results == target.resolve() or results.is_relative_to(target.resolve()):
        raise ReportFolderError(f"--out {out_dir} holds the results folder {results_dir}; the report replaces "
                                "its folder whole: choose a folder of its own (default: <results>/report)")
    if target.is_dir() and not is_report(target) and any(target.iterdir()):
        raise ReportFolderError(f"--out {out_dir} is a folder that is not an ilcforce report and not empty; the "
                                "report replaces its folder whole: choose a new or empty folder, or move it away")
    return target


def _remove_stale(target: Path) -> None:
    """Remove what killed reports left beside ``target`` (their partial folders; a previous report
    the two-rename fallback had not removed yet)."""
    with contextlib.suppress(OSError):
        for entry in target.parent.iterdir():
            found = _PARTIAL.match(entry.name)
            if found and found["name"] == target.name and not process_alive(int(found["pid"])) \
                    and entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry, ignore_errors=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where the system has no
    such call (the caller falls back to two renames)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    if renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def _move_into_place(staging: Path, target: Path) -> None:
    """``staging`` becomes ``target``; the previous ``target`` (a report, or an empty folder) is gone."""
    try:
        os.rename(staging, target)  # absent or empty: replaced in one step
        return
    except OSError as error:
        if error.errno not in (errno.ENOTEMPTY, errno.EEXIST):
            raise
    if not is_report(target):  # checked again: a folder made there while the report was being built
        raise ReportFolderError(f"{target} is now a folder that is not an ilcforce report and not empty (made "
                                "while the report was being built); it is left as it is, and the report not written")
    if _exchange(staging, target):  # staging now holds the previous report
        shutil.rmtree(staging, ignore_errors=True)
        return
    previous = target.with_name(f".{target.name}.previous-{os.getpid()}")
    os.rename(target, previous)  # no atomic exchange here: a stop between these two renames leaves
    os.rename(staging, target)   # the previous report whole beside, removed by the next report
    shutil.rmtree(previous, ignore_errors=True)


@contextlib.contextmanager
def building(target: Path) -> Iterator[Path]:
    """Within: a new empty hidden sibling of ``target`` to write the report into; removed on leaving
    unless :func:`publish` moved it into place."""
    _remove_stale(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    staging = target.with_name(f".{target.name}.partial-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    try:
        yield staging
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def publish(staging: Path, target: Path, version: str) -> None:
    """Mark ``staging`` as a report and move it into place (see the module's docstring). A stop
    signal arriving meanwhile is answered once the move is done, so it never falls between steps."""
    (staging / REPORT_MARKER).write_text(
        f"Written by ilcforce report {version}. The next `ilcforce report` to this folder replaces it "
        "whole.\n", encoding="utf-8")
    deferred: list[int] = []
    shield = (on_stop_signals(lambda signum, frame: deferred.append(signum))
              if threading.current_thread() is threading.main_thread() else contextlib.nullcontext())
    with shield:
        _move_into_place(staging, target)
    for signum in deferred:  # now answered by the command's own handlers
        signal.raise_signal(signum)
