"""Stop signals (Ctrl-C's SIGINT, and SIGTERM from `kill`, `timeout` or a batch system): the one place
ilcforce handles them.

Every command stops the same way on either: a run keeps every finished iteration, a study every
finished cell, a report is left unfinished; the command prints one line saying how it was stopped
and exits with 130 (SIGINT) or 143 (SIGTERM).

A signal must not break into a store's commit: inside HDF5's write-back of an object h5py is
releasing, h5py swallows the exception, and the commit would end "normally" with writes missing.
So the handlers call :func:`interrupt`, which inside :func:`critical` (each commit) only takes note;
the KeyboardInterrupt is raised when the commit has ended (committed or rolled back). The store
imports this module; this module imports nothing of ilcforce.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Callable

#: The stop signals (SIGINT, SIGTERM) that reached the command running in this process; cleared
#: as each command starts under :func:`stop_signals`.
STOPS: list[int] = []
#: Set once a command has printed its line about the stop (so the entry point does not add one).
ANNOUNCED: list[bool] = []


def terminated() -> bool:
    return signal.SIGTERM in STOPS


def stop_word() -> str:
    return "terminated (SIGTERM)" if terminated() else "interrupted"


def stop_code() -> int:
    return 143 if terminated() else 130


def announce(what: str) -> str:
    """The one line a command prints when a stop signal ended it: ``"<how>: <what>"``."""
    ANNOUNCED.append(True)
    return f"{stop_word()}: {what}"


@contextlib.contextmanager
def on_stop_signals(handler):
    """Within: ``handler(signum, frame)`` answers SIGINT and SIGTERM; the previous handlers are put
    back after (main thread only, as Python requires)."""
    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for sig, before in previous.items():
            signal.signal(sig, before)


def note(signum: int) -> None:
    """Record a stop signal (for handlers that do not raise, e.g. one that asks a loop to stop)."""
    STOPS.append(signum)


@contextlib.contextmanager
def stop_signals():
    """Within: SIGINT and SIGTERM note themselves in :data:`STOPS` and raise KeyboardInterrupt where
    they land. Should Python drop that KeyboardInterrupt (raised in a weakref or GC callback), a
    command that checks :data:`STOPS` between units of work stops there. Once a stop signal came,
    errors Python cannot raise (a destructor of an object the interrupt left half-built, e.g.
    llvmlite's) print nothing: the process is ending. Only the main thread sets handlers."""
    STOPS.clear()
    ANNOUNCED.clear()
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        STOPS.append(signum)
        interrupt()  # at once, or when a store's commit in progress has ended

    def unraisable(info) -> None:
        if not STOPS:
            hook(info)

    hook = sys.unraisablehook
    sys.unraisablehook = unraisable
    try:
        with on_stop_signals(handler):
            yield
    finally:
        sys.unraisablehook = hook


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


@contextlib.contextmanager
def deferred(say: Callable[[str], None]):
    """Within: the first Ctrl-C or SIGTERM asks to stop (yields the asking function: true once one
    came) and says so through ``say``; a second stops at once (as :func:`interrupt`).

    For a run, which looks at the request between chunks of its compiled loop: the iteration in
    flight is dropped, every finished one is stored. A KeyboardInterrupt raised wherever the signal
    lands (e.g. inside a garbage-collection callback, where Python ignores it) could be lost; a flag
    looked at between iterations cannot."""
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    requested = list(STOPS)  # a signal whose KeyboardInterrupt Python dropped still stops

    def handler(signum, frame):
        note(signum)
        if requested:
            interrupt()  # at once, or when the store's commit in progress has ended
            return
        requested.append(signum)
        say("stopping: the unfinished iteration is dropped, every finished one is stored")

    with on_stop_signals(handler):
        yield lambda: bool(requested)


def _stopped_while_starting(signum, frame) -> None:
    STOPS.append(signum)
    try:
        os.write(2, (announce("stopped before the command started") + "\n").encode())
    finally:
        os._exit(stop_code())


def answer_from_the_start() -> None:
    """Until a command's own handling starts (:func:`stop_signals`), end the process at a stop
    signal with the same one line and exit code as anywhere else. Python is then importing typer,
    the CLI and what the command needs, and a KeyboardInterrupt in the middle of an import would be
    a traceback. For the console entry point only: a notebook keeps its own Ctrl-C."""
    for stop in (signal.SIGINT, signal.SIGTERM):
        signal.signal(stop, _stopped_while_starting)
