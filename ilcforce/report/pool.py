"""Run the report's independent pieces (one experiment, one study's report, one study's findings)
in worker processes, heaviest first, with their progress lines shown as they happen.

Each piece writes its own files and returns what the index needs; the caller puts the results
together in a fixed order, so the report is the same whatever ``jobs`` is. Workers are forked
(they inherit the imported modules); a worker's progress lines travel back through a queue and
are printed by the parent through its ``progress`` callable, so ``--quiet`` silences them all.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import queue as queue_module
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from typing import Any

from ilcforce.stops import on_stop_signals

#: In a worker: the queue its progress lines go to (set by the pool's initializer).
_QUEUE: Any = None


@dataclass(frozen=True)
class Task:
    """One piece of the report: ``function(*args, progress=...)``, its label and its expected cost."""

    label: str
    function: Callable[..., Any]
    args: tuple
    cost: float = 1.0  # relative; the heaviest pieces start first so that no core idles at the end


def _init_worker(queue: Any) -> None:
    global _QUEUE
    _QUEUE = queue
    # a forked worker inherits the command's stop handlers; it leaves stopping to the parent, which
    # ends it (SIGTERM, default action) when the report is stopped. A terminal's Ctrl-C reaches the
    # whole process group: the parent alone acts on it.
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _end_workers(pool: ProcessPoolExecutor, grace: float = 2.0) -> None:
    """Stop a pool at once: queued pieces cancelled, running workers terminated (killed after
    ``grace`` seconds). ``shutdown`` alone runs every queued piece first (it took minutes).

    A stop signal arriving meanwhile (a second Ctrl-C) is answered only once every worker is
    ended: raised inside, it would leave the rest of them running, orphaned.
    """
    deferred: list[int] = []
    shield = (on_stop_signals(lambda signum, frame: deferred.append(signum))
              if threading.current_thread() is threading.main_thread() else contextlib.nullcontext())
    with shield:
        processes = list((getattr(pool, "_processes", None) or {}).values())
        manager = getattr(pool, "_executor_manager_thread", None)
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            if process.is_alive():
                process.terminate()
        deadline = time.monotonic() + grace
        for process in processes:
            process.join(max(0.0, deadline - time.monotonic()))
            if process.is_alive():
                process.kill()
                process.join(1.0)
        # the pool's manager thread sees its workers gone and closes its wake-up pipe: wait for that,
        # or Python's exit may write to the pipe as it closes ("Exception ignored ... Bad file
        # descriptor": a check-then-write race in Python 3.11's concurrent.futures, seen in a full test
        # run). shutdown(wait=False) above forgot the thread, so it is taken before.
        if manager is not None:
            manager.join(grace)
    for signum in deferred:  # now answered by the command's own handlers
        signal.raise_signal(signum)


def worker_progress(text: str) -> None:
    """A worker's progress callable: the line goes to the parent (dropped outside a pool)."""
    if _QUEUE is not None:
        _QUEUE.put(text)


def _drain(queue: Any, progress: Callable[[str], None] | None) -> None:
    while True:
        try:
            text = queue.get_nowait()
        except queue_module.Empty:
            return
        if progress is not None:
            progress(text)


def run_tasks(tasks: list[Task], *, jobs: int, progress: Callable[[str], None] | None = None) -> list[Any]:
    """Every task's result, in the order of ``tasks``. ``jobs`` worker processes (1: in this process).

    ``progress`` gets the tasks' own lines and one line per finished task ("<label> done, k of n").
    A task's exception is raised here, as it would be in this process.
    """
    results: list[Any] = [None] * len(tasks)
    done = 0

    def finished(index: int) -> None:
        nonlocal done
        done += 1
        if progress is not None:
            progress(f"{tasks[index].label} done ({done} of {len(tasks)})")

    if jobs <= 1 or len(tasks) <= 1:
        for index, task in enumerate(tasks):
            results[index] = task.function(*task.args, progress=progress)
            finished(index)
        return results
    context = multiprocessing.get_context("fork")  # workers inherit the imported modules
    queue = context.Queue()
    order = sorted(range(len(tasks)), key=lambda k: -tasks[k].cost)  # stable: equal costs keep their order
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=context,
                               initializer=_init_worker, initargs=(queue,))
    try:
        futures = {pool.submit(tasks[k].function, *tasks[k].args, progress=worker_progress): k for k in order}
        pending = set(futures)
        while pending:
            finished_now, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(queue, progress)
            for future in sorted(finished_now, key=lambda f: futures[f]):
                results[futures[future]] = future.result()
                finished(futures[future])
    except BaseException:  # a stop signal, or a piece's error: no worker outlives the command
        _end_workers(pool)
        raise
    pool.shutdown(wait=True)
    _drain(queue, progress)
    return results
