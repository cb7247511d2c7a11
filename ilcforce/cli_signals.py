"""Ctrl-C and SIGTERM (a batch system's, `kill`'s or `timeout`'s stop) in every command.

SIGTERM takes Ctrl-C's path: each command stops the way Ctrl-C stops it (a run keeps every finished
iteration, a study every finished cell), prints one line saying how it was stopped, and exits with
143 (130 for Ctrl-C). Before, `simulate`, `report` and `validate` died silently on SIGTERM.
"""

from __future__ import annotations

import contextlib
import signal
import sys
import threading

from ilcforce import interrupts

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
        interrupts.interrupt()  # at once, or when a store's commit in progress has ended

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
