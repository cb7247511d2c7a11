"""The study driver: runs the cells not yet stored, on Dask or in-process, and writes the study store.

Execution (``workers`` / ``scheduler``):

* ``workers=1`` (and no scheduler): in this process, one cell after another, no Dask at all
  (debugging, the test suite);
* default: a Dask ``LocalCluster`` of ``workers`` single-threaded worker processes (one per core);
* ``scheduler="tcp://HOST:PORT"``: an existing Dask cluster (``dask scheduler`` + ``dask worker``).

The Dask side (cluster, shared client, retries) is :mod:`ilcforce.study.dask_run`.

Workers return metrics only (:func:`ilcforce.study.cell.run_cell`); the driver is the only writer
of the study store. At most a few cells per worker are in flight at once, so the driver's and the
scheduler's memory stay flat in the number of cells. A cell that raises, or whose worker dies, is
retried once and then recorded as failed with its message; the study goes on.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import platform
import re
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ilcforce.study.cell import run_cell
from ilcforce.study.dask_run import (ATTEMPTS, CONNECT_TIMEOUT, IN_FLIGHT_PER_THREAD, SharedClient,
                                     describe_failure, dask_client, run_on_dask)
from ilcforce.study.spec import Cell, Study, StudyError
from ilcforce.store.provenance import git_state
from ilcforce.store.study import DONE, FAILED, StudyStore, check_usable

#: Source files whose change makes stored cells stale (the simulation, not reporters or CLI).
_NOT_FINGERPRINTED = ("report/", "cli/", "store", "study/", "tune/", "__main__.py")


#: A Dask scheduler address: [tcp:// or tls://]HOST:PORT (HOST a name, IPv4 or [IPv6]).
_ADDRESS = re.compile(r"(?:(?:tcp|tls)://)?(?:[A-Za-z0-9._-]+|\[[0-9A-Fa-f:.]+\]):\d{1,5}")


@dataclass(frozen=True)
class Progress:
    """What the driver reports after each cell (and once at the start)."""

    total: int  # cells of the study
    finished: int  # cells stored as done (skipped ones included)
    failed: int  # cells recorded as failed
    to_run: int  # cells this run set out to compute
    last: str  # one line about the cell just stored ("" at the start)


@dataclass(frozen=True)
class StudySummary:
    """What :func:`run_study` did."""

    path: Path
    total: int
    skipped: int  # already stored before this run
    ran: int  # computed in this run (done or failed)
    failed: tuple[tuple[Cell, str], ...]  # cells recorded as failed, with their message
    workers: int
    scheduler: str
    wall_time: float
    quarantined: tuple[str, ...] = ()  # one line per refused journal record moved aside (its cell ran again)


def fingerprint() -> str:
    """sha256 over the simulation's sources (everything but reporters, CLI, benchmarks and stores)."""
    root = Path(__file__).resolve().parent.parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        if rel.startswith(_NOT_FINGERPRINTED) and rel != "study/cell.py":
            continue
        digest.update(rel.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _versions() -> dict:
    from importlib.metadata import PackageNotFoundError, version

    import ilcforce

    out = {"ilcforce": ilcforce.__version__, "git_commit": git_state()[0], "python": platform.python_version()}
    for package in ("numpy", "numba", "h5py", "dask", "distributed"):
        with contextlib.suppress(PackageNotFoundError):
            out[package] = version(package)
    return out


def store_path(results_dir: Path, name: str) -> Path:
    return Path(results_dir) / "studies" / f"{name}.h5"


def cell_store_path(results_dir: Path, study: Study, cell: Cell) -> Path:
    """Where ``--keep-stores`` writes a cell's run store (an ``<experiment>/<method>.h5`` layout)."""
    return (Path(results_dir) / "studies" / study.name / "cells" / f"setting{cell.setting}-seed{cell.seed}"
            / f"{cell.method}.h5").resolve()


def _header(study: Study) -> dict:
    settings = [{"config_json": s.config.to_json(), "label": s.label(),
                 "values_json": json.dumps(dict(s.values))} for s in study.settings]
    return {"name": study.name, "description": study.description, "study_toml": study.source,
            "definition_json": json.dumps(study.definition(), sort_keys=True), "fingerprint": fingerprint(),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"), "settings": settings}


def check_store(study: Study, results_dir: Path | str = "results", *, resume: bool = False,
                overwrite: bool = False, replace_stale: bool = False) -> None:
    """Refuse now, in one line (StudyStoreError), what :func:`run_study` would refuse on opening the
    study's store: ``ilcforce study A.toml B.toml`` checks every store before any cell runs."""
    check_usable(store_path(results_dir, study.name), _header(study), overwrite=overwrite,
                 replace_stale=replace_stale, require_existing=resume)


def _run_in_process(jobs, function):
    for cell, args in jobs:
        for attempt in range(1, ATTEMPTS + 1):
            try:
                yield cell, attempt, function(*args), None
                break
            except Exception as exc:  # noqa: BLE001 - a failing cell is recorded, the study goes on
                if attempt == ATTEMPTS:
                    yield cell, attempt, None, describe_failure(exc)


def _warm_up(run, todo: list[Cell], study: Study) -> None:
    """Load the compiled kernels of the study's first setting in every worker (``run(f, *args)``
    runs f on each) before the first cell, so the cells' clock and the ETA start on warm workers
    whichever way they run. A failure here is left for the cells to report."""
    from ilcforce.experiment import preload_kernels

    config = study.cell_config(todo[0])
    with contextlib.suppress(Exception):
        run(preload_kernels, config, sorted({c.method for c in todo}))


# ------------------------------------------------------------------------------------------------


def max_local_workers() -> int:
    """The most local workers a study starts: 4 per core (64 on 2 cores took 48 s for 2 cells, and
    100,000 never started)."""
    return 4 * (os.cpu_count() or 1)


def run_study(study: Study, results_dir: Path | str = "results", *, workers: int | None = None,
              scheduler: str | None = None, resume: bool = False, overwrite: bool = False,
              replace_stale: bool = False, keep_stores: bool = False, command: str = "",
              timeout: float = CONNECT_TIMEOUT,
              progress: Callable[[Progress], None] | None = None,
              cell_function: Callable = run_cell, shared: SharedClient | None = None) -> StudySummary:
    """Run every cell of ``study`` not yet in ``results/studies/<name>.h5`` and store it.

    ``workers`` defaults to the number of usable cores; with ``scheduler`` it must be None.
    ``cell_function(config, method, keep_store_path)`` is :func:`run_cell` (tests inject faults).
    ``shared`` (a :class:`SharedClient`) lends its cluster instead of starting one for this study.
    Raises StudyStoreError (store cannot be used) or StudyRunError (no scheduler / workers) before
    any cell runs; KeyboardInterrupt after committing every finished cell.
    """
    if scheduler and workers is not None:
        raise StudyError("--workers does not apply with --scheduler (the cluster has its own workers)")
    if scheduler is not None and not _ADDRESS.fullmatch(scheduler):
        raise StudyError(f"--scheduler expects an address like tcp://HOST:PORT, got {scheduler!r}")
    if not (timeout > 0 and timeout < 3600):
        raise StudyError(f"--timeout must be more than 0 s and less than 3600 s, got {timeout:g}")
    if workers is not None and workers < 1:
        raise StudyError(f"--workers must be >= 1, got {workers}")
    if workers is not None and workers > max_local_workers():
        raise StudyError(f"--workers {workers} is more than this machine runs usefully: at most "
                         f"{max_local_workers()} (4 per core; each worker is a process running one cell at a time)")
    if workers is None and not scheduler:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    start = time.perf_counter()
    path = store_path(results_dir, study.name)
    session = {"id": uuid.uuid4().hex, "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
               "command": command, "scheduler": scheduler or ("in-process" if workers == 1 else "LocalCluster"),
               "workers": workers, "host": platform.node(), "versions": _versions(),
               # what this run set out to store, so that a report can say a stopped study is incomplete
               "cells_planned": len(study.cells()), "study_toml": study.source,
               # the cells this run may commit: a journal record of any other cell is refused
               "seeds": list(study.seeds), "methods": list(study.methods)}
    store = StudyStore(path, header=_header(study), session=session, overwrite=overwrite,
                       replace_stale=replace_stale, require_existing=resume)
    try:
        cells = study.cells()
        todo = [c for c in cells if (c.setting, c.seed, c.method) not in store.done]
        skipped = len(cells) - len(todo)
        jobs = ((c, (study.cell_config(c), c.method,
                     str(cell_store_path(results_dir, study, c)) if keep_stores else None)) for c in todo)
        failed_now: list[tuple[Cell, str]] = []
        ran = 0
        done_now = [0]

        def report(last: str) -> None:
            if progress is not None:
                progress(Progress(len(cells), skipped + done_now[0], len(failed_now), len(todo), last))

        if not todo:
            report("")
        if todo:
            with contextlib.ExitStack() as stack:
                if scheduler or workers > 1:
                    client = (shared.get(workers or 0, scheduler, timeout) if shared is not None
                              else stack.enter_context(dask_client(workers or 0, scheduler, timeout)))
                    if scheduler:
                        workers_seen = len(client.scheduler_info().get("workers", {}))
                        store.update_session(workers=workers_seen)
                    threads = max(1, sum(client.nthreads().values()))
                    if cell_function is run_cell:
                        _warm_up(lambda *a: client.run(*a), todo, study)
                    outcomes = run_on_dask(client, jobs, cell_function, IN_FLIGHT_PER_THREAD * threads)
                else:
                    if cell_function is run_cell:
                        _warm_up(lambda f, *a: f(*a), todo, study)
                    outcomes = _run_in_process(jobs, cell_function)
                report("")  # the workers are there: the clock of the ETA starts now
                try:
                    for cell, attempt, result, message in outcomes:
                        ran += 1
                        record = {"setting": cell.setting, "seed": cell.seed, "method": cell.method,
                                  "attempts": attempt}
                        if result is not None:
                            rows = result["rows"]
                            record.update(state=DONE, message="", elapsed=float(result["elapsed"]),
                                          worker=str(result["worker"]), rows=rows)
                            done_now[0] += 1
                            status = rows[-1]["status"] if rows else "empty"
                            last = f"{cell.method} seed {cell.seed} setting {cell.setting}: {status}"
                        else:
                            record.update(state=FAILED, message=message, elapsed=float("nan"), worker="", rows=[])
                            failed_now.append((cell, message))
                            last = f"{cell.method} seed {cell.seed} setting {cell.setting}: FAILED ({message})"
                        store.commit(record, time.perf_counter())
                        report(last)
                finally:
                    store.update_session(finished=datetime.now(timezone.utc).isoformat(timespec="seconds"))
                    store.consolidate(time.perf_counter())
        return StudySummary(path, len(cells), skipped, ran, tuple(failed_now), workers or 0,
                            scheduler or ("in-process" if workers == 1 else "LocalCluster"),
                            time.perf_counter() - start, tuple(store.quarantined))
    except BaseException:
        store.discard_if_unused()  # e.g. an unreachable scheduler: no empty store left behind
        raise
    finally:
        store.close()

