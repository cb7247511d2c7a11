"""Run a generator one step ahead in a background thread: simulate iteration j + 1 while j is stored.

The compiled loop releases the GIL (``nogil=True``), so on a machine with a free core the store's
writes and metrics of iteration j (Python and HDF5, in the consumer's thread) overlap with the
simulation of iteration j + 1 (in the producer's thread). The records handed over hold arrays
nobody writes again (``Controller.learned_state`` returns copies, or read-only views of the buffer
the next iteration only reads; the logs are fresh per iteration), so the stored numbers are those
of a serial run (pinned by ``tests/test_reference_run.py`` and
``tests/test_experiment.py``).

Order and errors are kept: items arrive in the producer's order, an exception raised by the producer
(including a KeyboardInterrupt from a stop request) is raised in the consumer after every item made
before it, and when the consumer stops early (an error while storing, a second Ctrl-C, ``break``)
the producer is asked to stop and is joined before the consumer's exception goes on.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")
_DONE = object()

#: How long the producer waits to hand over an item before looking at the stop flag again (s).
_POLL = 0.05


class Ahead(Generic[T]):
    """The items of ``make(stopping)``, produced in a background thread (started at once) up to
    ``depth`` ahead of the consumer; iterate once, in the consumer's thread. A context manager:
    leaving it (normally, by an error, or without having iterated at all) stops the producer within
    one chunk of its work and joins it. With ``join=False`` it does not wait: a producer of pure data
    (the next iterations' inputs) may finish the item it is making, e.g. a tau_d of seconds at a
    million samples, after a stop request has already been answered.

    ``make`` receives ``stopping()``, true once the consumer has gone away; the producer should pass
    it to whatever checks for a stop between chunks of work.
    """

    def __init__(self, make: Callable[[Callable[[], bool]], Iterator[T]], *, depth: int = 1,
                 name: str = "ilcforce-ahead", join: bool = True) -> None:
        self._join = join
        self._handoff: queue.Queue = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._make = make
        self._thread = threading.Thread(target=self._produce, name=name, daemon=True)
        self._thread.start()

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._handoff.put(item, timeout=_POLL)
                return True
            except queue.Full:
                continue
        return False

    def _produce(self) -> None:
        try:
            for item in self._make(self._stop.is_set):
                if not self._put((None, item)):
                    return
            self._put((None, _DONE))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            self._put((exc, None))

    def __iter__(self) -> Iterator[T]:
        try:
            while True:
                exc, item = self._handoff.get()
                if exc is not None:
                    raise exc
                if item is _DONE:
                    return
                yield item
        finally:
            self.close()

    def queued(self) -> int:
        """How many items are made and not yet taken."""
        return self._handoff.qsize()

    def close(self) -> None:
        """Stop the producer (within one chunk of its work) and wait for it."""
        self._stop.set()
        if self._join:
            self._thread.join()

    def __enter__(self) -> Ahead[T]:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class Turns:
    """When the simulation thread is inside the compiled loop, which runs without the GIL.

    A run's other threads (the inputs of the next iterations, the store's commits, the CLI's own
    imports) hold the GIL for a few milliseconds at a time. When one of them held it as an
    iteration ended, the simulation thread waited for it before it could start the next, and
    every 0.1 ms (the switch interval) the two took turns: its 1.5 ms between two iterations took
    3-15 ms. Those threads therefore :meth:`wait` until the loop runs before each piece
    of their work, which then overlaps the loop instead of the gap.
    """

    def __init__(self) -> None:
        self._inside = threading.Event()
        self._ready = threading.Event()
        self._over = False

    def enter(self) -> None:
        """The simulation thread is about to call the compiled loop."""
        self._inside.set()

    def leave(self) -> None:
        """The compiled loop returned."""
        if not self._over:
            self._inside.clear()

    def ready(self) -> None:
        """What the first iteration's end needs is made (the next iteration's inputs, tau_d)."""
        self._ready.set()

    def over(self) -> None:
        """The simulation has ended: nobody waits any more."""
        self._over = True
        self._inside.set()
        self._ready.set()

    def wait(self, timeout: float = 0.05) -> bool:
        """Wait until the compiled loop runs (or the simulation is over), at most ``timeout`` s."""
        return self._inside.wait(timeout)

    def wait_ready(self, timeout: float) -> bool:
        """Wait until the loop runs and the first iteration's end is provided for (:meth:`ready`):
        until then, work that can wait (the CLI's imports, the store's opening) would take the
        GIL from the threads that cannot."""
        return self._ready.wait(timeout)
