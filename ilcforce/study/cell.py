"""One cell of a study: (resolved config, method) -> metrics rows. Runs on a Dask worker or in-process.

The cell runs the very functions ``ilcforce simulate`` runs (:func:`ilcforce.experiment.simulate_iterations`
and :func:`ilcforce.metrics.iteration_metrics`, or :func:`ilcforce.experiment.run_method` itself when
the run store is kept), so its metrics are bit-identical to a single run of the same (config, seed,
method). It returns plain data and writes no study file: only the driver writes the study store.

Each row is one iteration: every column of :data:`ilcforce.metrics.METRIC_COLUMNS` plus, per learned
memory of the method, ``memory_norm_<name>`` (:func:`ilcforce.metrics.memory_norms`: the RMS over the
control grid of the Euclidean norm per sample of the memory after that iteration, NaN when it holds
a non-finite value, as after a divergence), and the same settled and at t = 0 alone
(``memory_settled_<name>``, ``memory_start_<name>``).

tau_d (:func:`ilcforce.simulate.desired_inputs`) depends only on the true plant, the wall, the
reference and the grids, not on the seed or the method, so each worker process keeps it in a
small cache keyed by exactly those (a study's 300 cells compute it twice per process, not 600 times).
"""

from __future__ import annotations

import os
import socket
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path


from ilcforce import metrics
from ilcforce.config import Config
from ilcforce.records import IterationRecord

#: Settings kept in a worker's tau_d cache (each entry is a few hundred kB at most).
_DESIRED_CACHE_SIZE = 32
_DESIRED: OrderedDict = OrderedDict()


def desired_cache(config: Config) -> dict:
    """This process's tau_d cache for ``config``'s wall, reference and grids (true plant -> arrays)."""
    key = (config.wall, config.reference, config.simulation.sample_time, config.simulation.log_every)
    cache = _DESIRED.get(key)
    if cache is None:
        cache = _DESIRED[key] = {}
        while len(_DESIRED) > _DESIRED_CACHE_SIZE:
            _DESIRED.popitem(last=False)
    else:
        _DESIRED.move_to_end(key)
    return cache


def run_cell(config: Config, method: str, keep_store: str | None = None,
             stop: Callable[[list[dict]], bool] | None = None) -> dict:
    """Run every iteration of ``method`` under ``config``; return the metrics rows.

    Parameters
    ----------
    config : Config
        The cell's resolved configuration (its ``experiment.seed`` is the cell's seed).
    method : str
        A registered method.
    keep_store : str or None
        If given, also write the full run store (today's format) at this path, replacing an
        ilcforce store left there by an earlier attempt.
    stop : callable or None
        Called with the rows so far after each iteration (not with ``keep_store``); True ends the run
        there (tuning's stability check prunes a trial whose learning grows).

    Returns
    -------
    dict
        ``rows`` (list of dicts, one per iteration run, keys as described in the module doc),
        ``elapsed`` (s of wall time in this call), ``worker`` (host:pid).
    """
    start = time.perf_counter()
    rows: list[dict] = []
    cache = desired_cache(config)

    k0 = metrics.settled_sample(config.simulation.sample_time)

    def collect(record: IterationRecord, row: dict) -> None:
        rows.append({**row, **metrics.memory_norms(record.memory, settled_from_sample=k0)})

    if keep_store:
        from ilcforce.experiment import run_method

        path = Path(keep_store)
        path.parent.mkdir(parents=True, exist_ok=True)
        run_method(config, method, path, overwrite=path.exists(), command=f"ilcforce study (cell {method}, "
                   f"seed {config.experiment.seed})", progress=collect, desired_cache=cache)
    else:
        from ilcforce.experiment import simulate_iterations

        for record in simulate_iterations(config, method, desired_cache=cache):
            collect(record, metrics.iteration_metrics(record))
            if stop is not None and stop(rows):
                break
    return {"rows": rows, "elapsed": time.perf_counter() - start,
            "worker": f"{socket.gethostname()}:{os.getpid()}"}
