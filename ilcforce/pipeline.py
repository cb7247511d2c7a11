"""Run a generator one step ahead in a background thread: simulate iteration j + 1 while j is stored.

The compiled loop releases the GIL (``nogil=True``), so on a machine with a free core the store's
writes and metrics of iteration j (Python and HDF5, in the consumer's thread) overlap with the
simulation of iteration j + 1 (in the producer's thread). Nothing is shared between the two but the
records handed over: each record is built from copies (``Controller.learned_state`` returns copies;
the logs are fresh arrays), so the stored numbers are those of a serial run (pinned by
``tests/test_reference_run.py`` and ``tests/test_experiment.py``).

Order and errors are kept: items arrive in the producer's order, an exception raised by the producer
(including a KeyboardInterrupt from a stop request) is raised in the consumer after every item made
before it, and when the consumer stops early (an error while storing, a second Ctrl-C, ``break``)
the producer is asked to stop and is joined before the consumer's exception goes on.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from typing import TypeVar

T = TypeVar("T")

#: How long the producer waits to hand over an item before looking at the stop flag again (s).
_POLL = 0.05


def ahead(make: Callable[[Callable[[], bool]], Iterator[T]], *, depth: int = 1) -> Iterator[T]:
    """Yield the items of ``make(stopping)``, produced in a background thread up to ``depth`` ahead.

    ``make`` receives ``stopping()``, true once the consumer has gone away; the producer should pass
    it to whatever checks for a stop between chunks of work (it then ends within one chunk).
    """
    handoff: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    done = object()

    def put(item) -> bool:
        while not stop.is_set():
            try:
                handoff.put(item, timeout=_POLL)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in make(stop.is_set):
                if not put((None, item)):
                    return
            put((None, done))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            put((exc, None))

    thread = threading.Thread(target=produce, name="ilcforce-ahead", daemon=True)
    thread.start()
    try:
        while True:
            exc, item = handoff.get()
            if exc is not None:
                raise exc
            if item is done:
                return
            yield item
    finally:
        stop.set()
        thread.join()
