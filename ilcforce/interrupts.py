"""Stop signals that would interrupt a store's commit wait until it is over.

A second Ctrl-C raises KeyboardInterrupt wherever the main thread is. Inside a commit that can be
inside HDF5's write-back of an object h5py is releasing, where h5py swallows the exception: the
commit then ended "normally" with writes missing, its undo journal was removed, and the store no
longer validated (found by an attack on the CLI: two SIGINTs 10 ms apart during the stop commit).
The signal handlers of the CLI call :func:`interrupt` instead of raising; within :func:`critical`
(each commit, :mod:`ilcforce.store.commit`) it only takes note, and the KeyboardInterrupt is raised
when the commit has ended (committed or rolled back), so a stop still takes effect within one
commit. No module here imports the CLI or the store: both import this one.
"""

from __future__ import annotations

import contextlib
import threading

_depth = [0]  # commits in progress in the main thread
_pending: list[bool] = []  # a KeyboardInterrupt waits for the commit to end


def interrupt() -> None:
    """Raise KeyboardInterrupt now, or when the main thread's commit in progress has ended."""
    if _depth[0] > 0 and threading.current_thread() is threading.main_thread():
        _pending.append(True)
        return
    raise KeyboardInterrupt


@contextlib.contextmanager
def critical():
    """A section that :func:`interrupt` does not break into (main thread; elsewhere a no-op)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _depth[0] += 1
    try:
        yield
    except BaseException:
        if _depth[0] == 1:
            _pending.clear()  # the section's own error ends the command; the stop was noted by the handler
        raise
    finally:
        _depth[0] -= 1
    if _depth[0] == 0 and _pending:
        _pending.clear()
        raise KeyboardInterrupt
