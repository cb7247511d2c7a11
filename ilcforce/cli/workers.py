"""Run several methods of one experiment at once: one forked worker process per method.

``compare`` runs the paper's study (c1, c2, c3) this way, so the methods share the machine's cores.
The workers are forked after the parent has imported the simulator and loaded the compiled
kernels, so no worker pays for imports or for loading numba's caches again. Each worker writes its
own store through the same :func:`ilcforce.experiment.run_method` as ``simulate`` (stored numbers
are identical whichever way a method ran) and reports each stored iteration to the parent, which
alone draws the progress display.

Interrupts: the workers run in their own process group, so a Ctrl-C reaches the parent only, which
passes each one on to every worker. The first makes every worker stop after the iteration it is on
has been stored (a valid "partial" store, ready for ``--resume``); a second stops them at once
(the store still holds every committed iteration). SIGTERM is passed on the same way.
"""

from __future__ import annotations

import contextlib
import multiprocessing
from multiprocessing import connection
import os
import signal
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from ilcforce import stops
from ilcforce.stops import note, on_stop_signals
from ilcforce.experiment import preload_kernels
from ilcforce.store import safeio

#: Exit status of a worker stopped by an interrupt (as the CLI's 130).
_INTERRUPTED = 130


@dataclass(frozen=True)
class Job:
    """One method to run into one store."""

    method: str
    path: Path
    overwrite: bool
    resume: bool
    command: str


@dataclass(frozen=True)
class Outcome:
    """How a worker ended: ``status`` is "complete", "diverged", "interrupted" or "error"."""

    method: str
    status: str
    message: str = ""  # the error's one-line message ("error" only)
    known: bool = True  # False: an unexpected exception; ``message`` holds its traceback


#: progress(method, iteration, status, metrics row) after each stored iteration
Progress = Callable[[str, int, str, dict], None]


def run_parallel(config, jobs: Sequence[Job], progress: Progress | None = None,
                 on_interrupt: Callable[[], None] | None = None,
                 meanwhile: Callable[[], None] | None = None) -> dict[str, Outcome]:
    """Run every job in a forked worker; return each method's :class:`Outcome` when all have ended.

    ``on_interrupt()`` is called in the parent at the first Ctrl-C (e.g. to say what happens next);
    ``meanwhile()`` once all workers have started (e.g. imports the parent needs afterwards).
    """
    preload_kernels(config, [job.method for job in jobs])
    context = multiprocessing.get_context("fork")
    workers: dict[str, multiprocessing.process.BaseProcess] = {}
    readers: dict[object, str] = {}  # one pipe per worker: a killed worker cannot block another's
    outcomes: dict[str, Outcome] = {}
    interrupts: list[int] = []

    def forward(signum, frame):
        interrupts.append(signum)
        note(signum)  # the command then says "interrupted" (130) or "terminated (SIGTERM)" (143)
        if len(interrupts) == 1 and on_interrupt is not None:
            on_interrupt()
        for method, worker in workers.items():
            if worker.pid is not None and method not in outcomes:
                try:
                    os.kill(worker.pid, signum)
                except ProcessLookupError:
                    pass

    with on_stop_signals(forward):
        try:
            for job in jobs:
                reader, writer = context.Pipe(duplex=False)
                worker = context.Process(target=_worker, args=(config, job, writer), name=f"ilcforce-{job.method}")
                worker.start()
                writer.close()  # the worker holds the only write end: its exit is seen as end of file
                workers[job.method], readers[reader] = worker, job.method
            if meanwhile is not None:
                meanwhile()
            while readers:
                for reader in connection.wait(list(readers), timeout=0.5):
                    method = readers[reader]
                    try:
                        kind, *payload = reader.recv()
                    except EOFError:
                        del readers[reader]
                        reader.close()
                        continue
                    if kind == "progress":
                        if progress is not None:
                            progress(method, *payload)
                    elif kind == "written":  # the worker's store, closed: no need to walk it again here
                        safeio.mark_walked(payload[0])
                    else:
                        outcomes[method] = Outcome(method, *payload)
            for worker in workers.values():
                worker.join()
            _collect_dead(workers, outcomes)
        finally:
            for worker in workers.values():  # only after an error in the parent itself
                if worker.is_alive():
                    worker.terminate()
                    worker.join()
    return outcomes


def _collect_dead(workers: dict, outcomes: dict[str, Outcome]) -> None:
    """A worker that ended without reporting (killed, out of memory) is an error, not a hang."""
    for method, worker in workers.items():
        if method not in outcomes and worker.exitcode is not None:
            code = worker.exitcode
            how = f"was killed by signal {-code}" if code < 0 else f"exited with code {code}"
            outcomes[method] = Outcome(method, "error", f"the worker running {method} {how}; its store holds "
                                                        "every iteration committed before (run the same command to continue)")


def _stop_with_parent(parent: int, requested: list[int]) -> None:
    """A worker whose parent dies (kill -9) gets SIGTERM and stops like at a Ctrl-C, after the
    iteration it is on is stored, releasing its store's lock; it ran on, orphaned, holding the lock,
    and a rerun of `compare` was refused. Linux's PR_SET_PDEATHSIG; elsewhere the worker runs on."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request was in place
        requested.append(signal.SIGTERM)


def _worker(config, job: Job, messages) -> None:  # messages: the write end of its pipe
    """In the forked process: run one method, report progress and how it ended, then exit."""
    from ilcforce.config import ConfigError
    from ilcforce.experiment import UnknownMethodError, run_method
    from ilcforce.store import StoreError

    parent = multiprocessing.parent_process().pid  # as forked: os.getppid() now may already be init's
    os.setpgrp()  # Ctrl-C at the terminal reaches the parent only; it forwards each one
    requested: list[int] = []

    def handler(signum, frame):
        note(signum)  # a KeyboardInterrupt Python drops (in a GC callback) then prints nothing
        if requested:
            stops.interrupt()  # at once, or when the store's commit in progress has ended
            return
        requested.append(signum)

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    _stop_with_parent(parent, requested)

    def tell(message: tuple) -> None:
        try:
            messages.send(message)
        except OSError:  # the parent is gone (kill -9): the run goes on, its store stays valid
            pass

    def tick(record, row):
        tell(("progress", record.iteration, record.status,
              {k: row[k] for k in ("position_error_2norm", "force_error_2norm")}))

    code = 0
    try:
        summary = run_method(config, job.method, job.path, overwrite=job.overwrite, resume=job.resume,
                             command=job.command, progress=tick, stop_requested=lambda: bool(requested))
        outcome = (summary.status,)
    except KeyboardInterrupt:
        outcome, code = ("interrupted",), _INTERRUPTED
    except (ConfigError, StoreError, UnknownMethodError) as exc:
        outcome, code = ("error", _first_line(exc)), 2
    except OSError as exc:
        outcome, code = ("error", f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": ")), 2
    except MemoryError as exc:
        outcome, code = ("error", f"out of memory: {exc}".rstrip(": ") + " (every finished iteration is stored)"), 2
    except BaseException:  # noqa: BLE001  (reported to the parent, which shows the traceback)
        outcome, code = ("error", traceback.format_exc(), False), 1
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the report must reach the parent
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if code == 0:
        with contextlib.suppress(OSError):
            tell(("written", safeio.file_key(job.path)))
    tell(("done", *outcome))
    messages.close()
    os._exit(code)


def _first_line(exc: BaseException) -> str:
    text = str(exc)
    return text.splitlines()[0] if text else type(exc).__name__
