"""The Dask side of a study: the cluster (a LocalCluster, or an existing scheduler by address), the
client shared by several studies, and the loop that keeps every worker fed and retries a failed
cell once. :mod:`ilcforce.study.runner` drives it and writes the store.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import time
import uuid

#: Seconds allowed to reach a remote scheduler, and then for a first worker to be there.
CONNECT_TIMEOUT = 10.0
WORKER_TIMEOUT = 30.0
#: Cells in flight per worker on a remote cluster (keeps every worker busy while the driver commits
#: results). A local cluster places exactly one cell per worker (``run_on_dask(pin=True)``).
IN_FLIGHT_PER_WORKER = 2
#: Tries per cell: the first run and one retry.
ATTEMPTS = 2
#: Dask's periodic housekeeping, turned down for a local cluster of busy single-task workers: idle,
#: a default 2-worker LocalCluster used about 12% of one core (driver 4.6%, each worker 3.5%:
#: system monitor every 0.5 s, memory monitor, work stealing, profiler); with these and
#: ``memory_limit=0`` (no memory monitor) about 1.4% (measured over 20 s idle, psutil CPU times).
#: Cells are submitted a few at a time per worker, so nothing is left to steal.
LEAN_LOCAL_CLUSTER = {"distributed.scheduler.work-stealing": False,
                      "distributed.admin.system-monitor.interval": "10s",
                      "distributed.worker.memory.monitor-interval": "10s",
                      "distributed.admin.tick.interval": "1s",
                      "distributed.worker.profile.enabled": False,
                      # Dask sets MALLOC_TRIM_THRESHOLD_ in its workers (to hand freed memory back to the
                      # OS); setting it turns off glibc's adaptive mmap threshold, so every large array a
                      # cell allocates is mmapped, faulted in and unmapped again: cells ran about 8% slower
                      # on a worker than in a plain process (15 cells: 8.2-8.5 s against 7.4-8.0 s)
                      "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}
class StudyRunError(Exception):
    """The study could not run (no scheduler, no workers); one line."""


def _one_line(text: object) -> str:
    return " ".join(str(text).split())[:500]


def describe_failure(exc: BaseException) -> str:
    if type(exc).__name__ == "KilledWorker":
        return "the worker process died while running the cell"
    return _one_line(f"{type(exc).__name__}: {exc}")


# ------------------------------------------------------------------------------------------------
# executors: each yields (cell, attempt, result dict or None, failure message or None)


@contextlib.contextmanager
def _quiet_dask():
    """Dask's own logging stays off the user's terminal (errors still show)."""
    names = ("distributed", "distributed.scheduler", "distributed.worker", "distributed.nanny",
             "distributed.core", "distributed.comm", "distributed.client", "bokeh", "tornado")
    saved = {name: logging.getLogger(name).level for name in names}
    for name in names:
        logging.getLogger(name).setLevel(logging.CRITICAL)
    try:
        yield
    finally:
        for name, level in saved.items():
            logging.getLogger(name).setLevel(level)


@contextlib.contextmanager
def dask_client(workers: int, scheduler: str | None, timeout: float = CONNECT_TIMEOUT):
    """A connected ``distributed.Client`` (and its LocalCluster when no scheduler is given)."""
    import dask
    from distributed import Client, LocalCluster

    # Local cluster only (a remote scheduler keeps its own configuration): a dead worker fails its
    # task at once (our retry-once applies), and a single-threaded worker holds one task at a time,
    # so a cell that kills its worker never takes an innocent cell down with it.
    settings = {"distributed.scheduler.allowed-failures": 0,
                "distributed.scheduler.worker-saturation": 1.0,
                "distributed.worker.daemon": False,
                "distributed.admin.system-monitor.gil.enabled": False,
                "logging.distributed": "error",
                **LEAN_LOCAL_CLUSTER}
    with _quiet_dask(), dask.config.set(settings):
        if scheduler:
            _probe(scheduler, timeout)
            failure = None
            try:
                client = Client(scheduler, timeout=timeout, set_as_default=False)
            except Exception as exc:  # noqa: BLE001 - anything at that address that is not a scheduler
                failure = f"{type(exc).__name__}: {_one_line(exc)[:120]}"
            if failure is not None:  # outside the except block, so the failed Client can be collected
                _forget_failed_client()
                raise StudyRunError(f"cannot connect to a Dask scheduler at {scheduler} within {timeout:g} s "
                                    f"({failure})")
            try:
                try:
                    client.wait_for_workers(1, timeout=WORKER_TIMEOUT)
                except (OSError, TimeoutError):
                    raise StudyRunError(f"the Dask scheduler at {scheduler} has no worker after "
                                        f"{WORKER_TIMEOUT:g} s (start one with `dask worker {scheduler}`)") from None
                yield client
            finally:
                client.close()
            return
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, memory_limit=0,
                               dashboard_address=None, silence_logs=logging.CRITICAL,
                               # the scheduler's HTTP endpoint (health, metrics) on a free local port:
                               # no clash with another cluster on 8787, no "port in use" warning
                               scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
        try:
            client = Client(cluster, set_as_default=False)
            try:
                yield client
            finally:
                client.close()
        finally:
            cluster.close()


class SharedClient:
    """One Dask client for several studies run one after another (``ilcforce study A.toml B.toml``):
    the cluster starts when the first study with cells to run needs it, and its workers stay warm."""

    def __init__(self) -> None:
        self._stack = contextlib.ExitStack()
        self._client = None

    def get(self, workers: int, scheduler: str | None, timeout: float):
        if self._client is None:
            self._client = self._stack.enter_context(dask_client(workers, scheduler, timeout))
        return self._client

    def __enter__(self) -> SharedClient:
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()


def _probe(scheduler: str, timeout: float) -> None:
    """Fail fast, with one line, when nothing listens at the scheduler's address."""
    import socket

    host, port = scheduler.split("://")[-1].rsplit(":", 1)
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise StudyRunError(f"cannot reach the Dask scheduler at {scheduler} within {timeout:g} s ({reason})") from None


def _forget_failed_client() -> None:
    """A Client whose constructor failed tries to close itself when collected and prints a traceback
    from ``__del__``; collect it now, with that message silenced."""
    import gc
    import sys

    hook = sys.unraisablehook
    sys.unraisablehook = lambda _info: None
    try:
        gc.collect()
    finally:
        sys.unraisablehook = hook


def run_on_dask(client, jobs, function, in_flight: int, *, pin: bool = False):
    """Yield (cell, attempt, result or None, failure message or None) as cells finish; a failed cell
    is submitted once more.

    ``pin`` (a local cluster of single-threaded workers): each cell goes to a worker holding no other
    cell, so a cell that kills its worker never takes another down with it. Without it (a remote
    cluster, whose workers may have several threads) at most ``in_flight`` cells are submitted at once
    and Dask places them; a second cell waiting on a worker that dies fails with it (Dask fails every
    task a dead worker held), which on a local cluster recorded innocent cells as failed.
    """
    from distributed import as_completed

    pending = iter(jobs)
    retries: collections.deque = collections.deque()
    lookahead: list = []
    meta: dict = {}  # key -> (cell, args, attempt, worker or None)
    queue = as_completed(loop=client.loop)

    def take():
        if retries:
            return retries.popleft()
        if lookahead:
            return lookahead.pop()
        for cell, args in pending:
            return cell, args, 1
        return None

    def more() -> bool:
        if retries or lookahead:
            return True
        for cell, args in pending:
            lookahead.append((cell, args, 1))
            return True
        return False

    def submit(job, worker=None) -> None:
        cell, args, attempt = job
        # allow_other_workers: should the worker be gone by now, the cell still runs elsewhere
        placement = {"workers": [worker], "allow_other_workers": True} if worker else {}
        future = client.submit(function, *args, key=f"cell-{cell.key}-try{attempt}-{uuid.uuid4().hex[:8]}",
                               pure=False, retries=0, **placement)
        meta[future.key] = (cell, args, attempt, worker)
        queue.add(future)

    workers: list = []  # pin: the workers' addresses, as last asked of the scheduler
    most = 0  # pin: the most workers seen at once

    def fill(refresh: bool = False) -> None:
        nonlocal workers, most
        if not pin:
            while len(meta) < in_flight and (job := take()) is not None:
                submit(job)
            return
        # asked at the start, after a failure (a restarted worker has a new address) and until as
        # many are back; otherwise a freed worker is reused at once (asking on every cell left each
        # worker idle about 25 ms a cell)
        if refresh or len(workers) < most:
            workers = list(client.nthreads())
            most = max(most, len(workers))
        busy = {entry[3] for entry in meta.values()}
        for worker in workers:
            if worker not in busy and (job := take()) is not None:
                submit(job, worker)

    fill(refresh=True)
    try:
        while True:
            for future in queue:
                cell, args, attempt, _ = meta.pop(future.key)
                if future.status == "finished":
                    fill()  # the freed worker starts its next cell while this one is fetched and committed
                    result = future.result()
                    future.release()
                    yield cell, attempt, result, None
                    continue
                message = describe_failure(future.exception())
                future.release()
                if attempt < ATTEMPTS:
                    retries.append((cell, args, attempt + 1))
                fill(refresh=True)
                if attempt >= ATTEMPTS:
                    yield cell, attempt, None, message
            if not more():
                return
            # cells left but none in flight: every worker was restarting when they were placed
            try:
                client.wait_for_workers(1, timeout=WORKER_TIMEOUT)
            except (OSError, TimeoutError):
                raise StudyRunError(f"no Dask worker came back within {WORKER_TIMEOUT:g} s") from None
            time.sleep(0.2)
            fill(refresh=True)
    finally:
        for key in list(meta):
            with contextlib.suppress(Exception):
                client.cancel(key)
