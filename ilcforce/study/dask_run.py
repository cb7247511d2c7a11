"""The Dask side of a study: the cluster (a LocalCluster, or an existing scheduler by address), the
client shared by several studies, and the loop that keeps every worker fed and retries a failed
cell once. :mod:`ilcforce.study.runner` drives it and writes the store.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import threading
import time
import uuid
from pathlib import Path

#: Seconds allowed to reach a remote scheduler, and then for a first worker to be there.
CONNECT_TIMEOUT = 10.0
WORKER_TIMEOUT = 30.0
#: Cells in flight per worker thread: the scheduler runs one per thread and queues the rest
#: (:func:`_cell_task`), so a freed worker starts its next cell without waiting for the driver.
IN_FLIGHT_PER_THREAD = 2
#: Tries per cell: the first run and one retry.
ATTEMPTS = 2
#: Seconds a local cluster may take to start before the study gives up on it (a worker stopped or
#: hung while it starts made a study wait for more than 20 minutes). Two workers start in 3-8 s on
#: a loaded 2-core machine; 64 took 48 s.
CLUSTER_START_TIMEOUT = 120.0
#: Seconds a local worker may go without a heartbeat before the scheduler has its nanny restart it
#: (its cell then fails that attempt and is retried): a frozen worker (``kill -STOP``, a hung
#: machine) no longer stalls a study. Dask's default is 5 minutes, checked every 5 minutes, so up to
#: 10; a worker's event loop heartbeats every 0.5 s while the compiled loop runs without the GIL.
LOCAL_WORKER_TTL = 30.0
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
    # task at once (our retry-once applies), and the scheduler sends a single-threaded worker one
    # queued cell at a time (_cell_task), so a cell that kills its worker never takes an innocent
    # cell down with it; a worker that stops answering is restarted (LOCAL_WORKER_TTL).
    settings = {"distributed.scheduler.allowed-failures": 0,
                "distributed.scheduler.worker-saturation": 1.0,
                "distributed.worker.daemon": False,
                "distributed.admin.system-monitor.gil.enabled": False,
                "distributed.scheduler.worker-ttl": f"{LOCAL_WORKER_TTL:g}s",
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
        def make():
            cluster = LocalCluster(n_workers=0, processes=True, dashboard_address=None,
                                   silence_logs=logging.CRITICAL,
                                   # the scheduler's HTTP endpoint (health, metrics) on a free local
                                   # port: no clash with another cluster on 8787, no "port in use" warning
                                   scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
            try:
                local.start(cluster, workers, settings, time.monotonic() + CLUSTER_START_TIMEOUT + 5.0)
            except BaseException:
                local.close()
                cluster.close()
                raise
            return cluster

        local = LocalWorkers()
        try:
            cluster = start_local_cluster(make, CLUSTER_START_TIMEOUT)
        except StudyRunError:
            local.close()
            raise
        except Exception as exc:  # noqa: BLE001 - e.g. a worker process killed while it started
            failure = f"{type(exc).__name__}: {_one_line(exc)[:200]}"
        except BaseException:  # a stop signal
            local.close()
            raise
        else:
            failure = None
        if failure is not None:  # outside the except block: no chained traceback is kept alive
            local.close()
            raise StudyRunError(f"the local Dask cluster of {workers} workers did not start ({failure})")
        try:
            client = Client(cluster, set_as_default=False)
            try:
                yield client
            finally:
                client.close()
        finally:
            local.close()
            cluster.close()


#: held while a worker process is started, and by a stop that closes starting (``_give_up``): a stop then
#: sees every worker process already started, and no new one starts after it
_SPAWN_LOCK = threading.Lock()
_SPAWN = {"closed": False}
#: Seconds a local worker process has to end after SIGTERM before it is killed.
WORKER_END_GRACE = 2.0
#: A local worker process's program, run as a file (``python -P``: without ``ilcforce.study``'s package
#: import, h5py and pandas among it, about 0.9 s of a worker's start).
LOCAL_WORKER = Path(__file__).with_name("local_worker.py")


class LocalWorkers:
    """The worker processes of a local cluster: ``python -P ilcforce/study/local_worker.py``, each Dask's
    nanny of one single-threaded worker, started here through ``subprocess`` (no patch of
    multiprocessing).

    * Each starts in a process group of its own, so a terminal's Ctrl-C, which reaches the whole
      foreground group, is the driver's alone (the workers printed KeyboardInterrupt tracebacks from
      wherever it found them); the driver stops the cluster itself. The driver keeps its own
      handlers all along (SIGINT ignored while the cluster started, for the workers to inherit, lost
      the Ctrl-C: the study ran to its end and exited 0).
    * Their output goes to /dev/null (Dask's logging is not the user's; a cell's error comes back
      through its future, and the warnings multiprocessing's resource tracker printed about the
      semaphores of workers killed while they started are theirs alone).
    * They hold the read end of a pipe whose write end only the driver holds, and exit when it
      closes: no worker outlives its driver, however the driver ends (kill -9 included).
    * None is started after a stop (``_give_up`` closes starting; a worker that Dask started as the
      driver unwound read its start-up data from a closed pipe and printed an EOFError traceback).
    """

    def __init__(self) -> None:
        self.processes: list = []
        self._alive: int | None = None  # the driver's write end of the pipe the workers watch
        self._closing = threading.Lock()  # the start's thread and a stop may both close

    def start(self, cluster, count: int, settings: dict, deadline: float) -> None:
        """Start ``count`` worker processes for ``cluster``'s scheduler and wait until each has joined
        it (until ``deadline``, a ``time.monotonic()``)."""
        import json
        import subprocess
        import sys

        watched, self._alive = os.pipe()
        try:
            address = cluster.scheduler_address
            config = json.dumps(settings)
            for index in range(count):
                with _SPAWN_LOCK:
                    if _SPAWN["closed"]:
                        raise StudyRunError("the study is stopping: no new worker process is started")
                    self.processes.append(subprocess.Popen(
                        [sys.executable, "-P", str(LOCAL_WORKER), address, f"local-{index}", str(watched), config],
                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                        pass_fds=(watched,), process_group=0))
        finally:
            os.close(watched)
        while len(cluster.scheduler_info.get("workers", ())) < count:
            for process in self.processes:
                if process.poll() is not None:
                    raise StudyRunError(f"a local worker process ended while the cluster started "
                                        f"(exit status {process.returncode})")
            if _SPAWN["closed"]:
                raise StudyRunError("the study is stopping: the cluster's start is given up")
            if time.monotonic() > deadline:  # the driver gives up first (start_local_cluster); this ends the wait
                raise StudyRunError(f"the local Dask cluster did not start within {CLUSTER_START_TIMEOUT:g} s "
                                    "(a worker hung while it started?)")
            time.sleep(0.05)

    def close(self) -> None:
        """End every worker process: SIGTERM to its group, SIGKILL after :data:`WORKER_END_GRACE`."""
        import signal

        with self._closing:
            processes, self.processes = self.processes, []
            alive, self._alive = self._alive, None
        for process in processes:
            with contextlib.suppress(OSError):
                os.killpg(process.pid, signal.SIGTERM)
        deadline = time.monotonic() + WORKER_END_GRACE
        for process in processes:
            with contextlib.suppress(Exception):
                process.wait(max(0.0, deadline - time.monotonic()))
        for process in processes:
            if process.poll() is None:
                with contextlib.suppress(OSError):
                    os.killpg(process.pid, signal.SIGKILL)
                with contextlib.suppress(Exception):
                    process.wait(5)
        if alive is not None:
            os.close(alive)


def start_local_cluster(make, timeout: float):
    """``make()`` (which starts a LocalCluster and its workers) run in a helper thread, with a stop that
    always works.

    * The main thread keeps its handlers and waits in steps of 0.1 s, so Ctrl-C and SIGTERM act at
      once, cluster start included (the helper thread blocks SIGINT, so Python's C-level handler
      runs in the main thread and wakes its wait).
    * After ``timeout`` s (a worker stopped or hung while it starts) the start is given up on:
      StudyRunError, one line.

    Whichever way the start is left before it ended, every process it started is killed (they are
    children of this process started since the call; a stopped one too), so none outlives the study.
    """
    import signal

    before = _child_pids()
    box: dict = {}
    with _SPAWN_LOCK:
        _SPAWN["closed"] = False

    def target() -> None:
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
        try:
            box["cluster"] = make()
        except BaseException as exc:  # noqa: BLE001 - handed to the main thread
            box["error"] = exc

    thread = threading.Thread(target=target, name="ilcforce: local cluster start", daemon=True)
    deadline = time.monotonic() + timeout
    try:
        thread.start()
        while thread.is_alive():
            thread.join(0.1)
            if thread.is_alive() and time.monotonic() > deadline:
                raise StudyRunError(f"the local Dask cluster did not start within {timeout:g} s (a worker "
                                    "hung while it started?); its processes were stopped")
    except BaseException:
        _give_up(before, thread)
        raise
    if "error" in box:
        _give_up(before, thread)
        raise box.pop("error")
    return box["cluster"]


def _give_up(before: set[int], thread) -> None:
    """Kill the processes a cluster start made (descendants since ``before``), so the start fails in its
    thread and unwinds (waited for up to 3 s). Not a nanny's multiprocessing resource tracker: it ends
    by itself once the processes that hold its pipe are gone, after unlinking the killed workers'
    semaphores."""
    with _SPAWN_LOCK:  # no worker process is being started now, and none will be
        _SPAWN["closed"] = True
    _kill_new_children(before, lambda cmdline: "resource_tracker" not in cmdline)
    thread.join(3.0)


def _child_pids() -> set[int]:
    import psutil

    with contextlib.suppress(psutil.Error):
        return {child.pid for child in psutil.Process().children(recursive=True)}
    return set()


def _kill_new_children(before: set[int], which) -> None:
    """SIGKILL every descendant of this process not in ``before`` whose command line passes ``which``
    (a stopped one dies too) and reap it."""
    import psutil

    try:
        children = [c for c in psutil.Process().children(recursive=True) if c.pid not in before]
    except psutil.Error:
        return
    chosen = []
    for child in children:
        with contextlib.suppress(psutil.Error):
            if which(" ".join(child.cmdline())):
                chosen.append(child)
    children = chosen
    for child in children:
        with contextlib.suppress(psutil.Error):
            child.kill()
    psutil.wait_procs(children, timeout=5)


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
    """Fail fast, with one line, when nothing listens at the scheduler's address, or when what
    listens is not a Dask scheduler: a scheduler sends its handshake the moment it accepts a
    connection, and Dask's own client waited for ever on a server that never does (an HTTP server,
    a listener that only accepts)."""
    import select
    import socket

    host, port = scheduler.split("://")[-1].rsplit(":", 1)
    started = time.monotonic()
    try:
        connection = socket.create_connection((host.strip("[]"), int(port)), timeout=timeout)
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc))
        raise StudyRunError(f"cannot reach the Dask scheduler at {scheduler} within {timeout:g} s ({reason})") from None
    with connection:
        left = max(0.0, timeout - (time.monotonic() - started))
        readable, _, _ = select.select([connection], [], [], left)
    if not readable:
        raise StudyRunError(f"{scheduler} accepts connections but sent no Dask handshake within {timeout:g} s: "
                            "not a Dask scheduler?")


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


def _cell_task(key: str, function, args):
    """The cell as a Dask task marked as a data producer: the scheduler then holds it in its queue and
    hands each worker only as many cells as it has threads (``worker-saturation`` 1.0 on a local
    cluster), dispatching the next one itself the moment a worker frees up. So a cell that kills its
    worker never takes a waiting cell down with it (Dask fails every task a dead worker held), and a
    cell needs no worker restriction: a task restricted to a worker that died while no worker was
    running stays in Dask's ``no-worker`` state for good, even with ``allow_other_workers`` (the
    scheduler does not offer it to workers that join later).

    The flag is private to Dask (``Task``'s, dask >= 2025.1) and Dask offers no public way to queue a
    task so: pyproject.toml pins the releases that have it, and tests/test_private_imports.py lists it
    with its reason. A Dask outside the pin without it is one line (:class:`StudyRunError`), not a
    traceback from inside the study.
    """
    try:
        from dask._task_spec import Task, parse_input

        return Task(key, function, *(parse_input(a) for a in args), _data_producer=True)
    except (ImportError, TypeError) as exc:
        failure = type(exc).__name__
    import dask

    raise StudyRunError(f"this Dask ({dask.__version__}) has no dask._task_spec.Task(..., _data_producer=True) "
                        f"({failure}), which queues a study's cells; install the release ilcforce pins: "
                        f"pip install '{DASK_REQUIREMENT}'")


#: The Dask releases that have the data-producer flag of :func:`_cell_task` (as pinned in pyproject.toml).
DASK_REQUIREMENT = "dask[distributed]>=2025.1,<2026.9"


def run_on_dask(client, jobs, function, in_flight: int):
    """Yield (cell, attempt, result or None, failure message or None) as cells finish; a failed cell
    is submitted once more.

    At most ``in_flight`` cells are submitted at once (keep it about twice the cluster's threads, so
    a freed worker finds its next cell in the scheduler's queue). Every outcome is read through
    ``future.result()``: a result lost with its worker before it was fetched is computed again and
    returned (the future is then not "finished" for a while, which is no failure), and a failure,
    the cell's own or that recomputation's, raises and counts as an attempt. Not
    ``as_completed(with_results=True)``: when the recomputation fails, it drops the future and its
    iterator waits for ever.
    """
    from distributed import as_completed

    pending = iter(jobs)
    retries: collections.deque = collections.deque()
    meta: dict = {}  # key -> (cell, args, attempt, future)
    queue = as_completed(loop=client.loop)

    def take():
        if retries:
            return retries.popleft()
        for cell, args in pending:
            return cell, args, 1
        return None

    def fill() -> None:
        while len(meta) < in_flight and (job := take()) is not None:
            cell, args, attempt = job
            key = f"cell-{cell.key}-try{attempt}-{uuid.uuid4().hex[:8]}"
            future = client.get({key: _cell_task(key, function, args)}, key, sync=False)
            meta[key] = (cell, args, attempt, future)
            queue.add(future)

    try:
        fill()
        # fill() tops up after every outcome (a retry included) and as_completed takes the futures
        # added meanwhile, so the loop ends only when every cell has its outcome
        for future in queue:
            cell, args, attempt, _ = meta.pop(future.key)
            result = message = None
            try:  # a result lost with its worker is computed again first (and that can fail)
                result = future.result()
            except Exception as exc:  # noqa: BLE001 - the cell's error, or KilledWorker: this attempt failed
                if _scheduler_lost(client, exc):  # not the cell's doing: it is not recorded at all
                    raise _lost(client, exc) from None
                message = describe_failure(exc)
            future.release()
            if message is not None and attempt < ATTEMPTS:
                retries.append((cell, args, attempt + 1))
            fill()
            if message is None:
                yield cell, attempt, result, None
            elif attempt >= ATTEMPTS:
                yield cell, attempt, None, message
    except StudyRunError:
        raise
    except Exception as exc:  # noqa: BLE001 - submitting to, or waiting on, a client whose scheduler is gone
        if not _scheduler_lost(client, exc):
            raise
        raise _lost(client, exc) from None
    finally:
        if meta and getattr(client, "status", "") == "running":
            with contextlib.suppress(Exception):
                client.cancel([entry[3] for entry in meta.values()])


def _scheduler_lost(client, exc: BaseException) -> bool:
    """Whether ``exc`` says the client lost its scheduler (its futures are then cancelled by the
    client, which the study itself never does while it waits on them), rather than a cell failed."""
    return (type(exc).__name__ in ("CancelledError", "FutureCancelledError", "ClosedClientError", "CommClosedError")
            or getattr(client, "status", "running") != "running")


def _lost(client, exc: BaseException) -> StudyRunError:
    where = getattr(getattr(client, "scheduler", None), "address", None) or "the Dask scheduler"
    return StudyRunError(f"lost the connection to {where} ({type(exc).__name__}); every finished cell is "
                         "stored, rerun the same command to continue")
