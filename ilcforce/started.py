"""Iterations simulating in a background thread before and while their consumer stores them.

:func:`start_iterations` starts the work of :func:`ilcforce.experiment.simulate_iterations` at once (the
CLI's early start, ``run_method``); the consumer takes the records from the :class:`StartedRun`,
each completed in its own thread (tau_d and the memory attached, the log signals taken out of the
loop's buffer), while the simulation goes on.
"""

from __future__ import annotations

from collections.abc import Callable

from ilcforce import pipeline
from ilcforce.config import Config


class StartedRun:
    """Iterations of one method simulating in a background thread (:func:`start_iterations`), up to
    :func:`records_ahead` finished records ahead of their consumer. A context manager: leaving it
    stops the simulation within one chunk of the compiled loop and joins its thread."""

    def __init__(self, config: Config, method: str, first: int, memory: dict | None,
                 stop_requested: Callable[[], bool] | None, chunk_steps: int | None,
                 desired_cache: dict | None) -> None:
        self.config_toml, self.method, self.first = config.to_toml(), method, first
        self.turns = pipeline.Turns()  # the compiled loop runs (iteration `first` has begun), or it is over
        self._stop_requested = stop_requested

        def make(consumer_gone):
            def stopping() -> bool:
                asked = self._stop_requested
                return consumer_gone() or (asked is not None and asked())
            from ilcforce.experiment import _unfinished_iterations

            return _unfinished_iterations(config, method, first, memory, stopping, chunk_steps, desired_cache,
                                          True, self.turns)

        self._ahead = pipeline.Ahead(make, depth=records_ahead(config))

    def is_for(self, config: Config, method: str) -> bool:
        """Whether these are the iterations of ``method`` with ``config`` (compared as the stored TOML)."""
        return self.method == method and self.config_toml == config.to_toml()

    def watch(self, stop_requested: Callable[[], bool] | None) -> None:
        """From now on the simulation stops when ``stop_requested()`` is true (as when started with it)."""
        self._stop_requested = stop_requested

    def records(self):
        """The :class:`IterationRecord` of each iteration, in order (iterate once); each completed
        here, in the taker's thread."""
        return (unfinished.complete() for unfinished in self._ahead)

    def queued(self) -> int:
        """How many finished records wait to be taken."""
        return self._ahead.queued()

    def close(self) -> None:
        self._ahead.close()

    def __enter__(self) -> StartedRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_iterations(config: Config, method: str, first: int = 0, memory: dict | None = None,
                     stop_requested: Callable[[], bool] | None = None, chunk_steps: int | None = None,
                     desired_cache: dict | None = None) -> StartedRun:
    """Start the iterations of :func:`ilcforce.experiment.simulate_iterations` (with ``prefetch``) in a
    background thread at once; the taker completes each record (:meth:`StartedRun.records`).

    Iteration j + 1 simulates (compiled loop, GIL released) while the consumer stores j."""
    from ilcforce.experiment import make_controller

    make_controller(config, method)  # a bad method fails here, not in the thread
    return StartedRun(config, method, first, memory, stop_requested, chunk_steps, desired_cache)


#: Bytes of finished records the simulation may run ahead of the store by (see :func:`records_ahead`).
RECORDS_AHEAD_BYTES = 64 * 1024**2


#: At most this many finished iterations wait for the store.
MAX_RECORDS_AHEAD = 8


def records_ahead(config: Config) -> int:
    """How many finished iterations may wait for the store (1 to :data:`MAX_RECORDS_AHEAD`): enough
    that the simulation does not wait while the store opens, within :data:`RECORDS_AHEAD_BYTES` of
    records (a record holds at most about 56 float64 per control sample:
    :func:`ilcforce.config_load.run_footprint`). A cold ``simulate`` opens its store (typer's and
    h5py's imports, the file's first commit) about 0.2 s after iteration 0 starts: with four
    records, the paper's run (7 allowed) waited 20-50 ms at its fifth iteration (issue 12)."""
    record_bytes = 56 * 8 * config.n_control
    return max(1, min(MAX_RECORDS_AHEAD, RECORDS_AHEAD_BYTES // max(1, record_bytes)))
