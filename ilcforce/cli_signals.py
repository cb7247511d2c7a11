"""SIGTERM (a batch system's, `kill`'s or `timeout`'s stop) takes Ctrl-C's path in every command.

Before, `simulate`, `report` and `validate` died silently on SIGTERM (exit 143, no line); now each
command stops the way Ctrl-C stops it (a run keeps every finished iteration, a study every finished
cell), prints one line saying it was terminated, and exits with 143 (130 for Ctrl-C).
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

#: Non-empty once a SIGTERM reached the command running in this process (cleared as each starts).
TERMINATED: list[int] = []


def stop_word() -> str:
    return "terminated (SIGTERM)" if TERMINATED else "interrupted"


def stop_code() -> int:
    return 143 if TERMINATED else 130


@contextlib.contextmanager
def sigterm_as_interrupt():
    """Within: SIGTERM raises KeyboardInterrupt where it lands, as Ctrl-C does, after noting itself
    in :data:`TERMINATED`. Should Python drop that KeyboardInterrupt (raised in a weakref or GC
    callback), a command that checks :data:`TERMINATED` between units of work stops there, and the
    dropped exception prints no "Exception ignored" traceback. Only the main thread sets handlers."""
    TERMINATED.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        TERMINATED.append(signum)
        raise KeyboardInterrupt

    def unraisable(info) -> None:
        if not (TERMINATED and info.exc_type is KeyboardInterrupt):
            hook(info)

    hook = sys.unraisablehook
    previous = signal.signal(signal.SIGTERM, handler)
    sys.unraisablehook = unraisable
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
        sys.unraisablehook = hook
