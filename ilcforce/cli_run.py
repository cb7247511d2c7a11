"""Running methods from the CLI: one live display over a run (or over parallel runs, one per
method, ``ilcforce.parallel``), and Ctrl-C handled so that every finished iteration is stored.

Used by ``simulate`` and ``compare`` in :mod:`ilcforce.cli`; no science here either.
"""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

from ilcforce.cli import CliError, _g, _say, err  # imported by cli's commands, once cli is loaded
from ilcforce.cli_signals import STOPS, note, on_stop_signals


def _progress_bar(disable: bool):
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    # no refresh thread: the display is redrawn at each update (and so nothing runs while compare forks)
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[last]}"), TimeElapsedColumn(), console=err.console(),
                    transient=False, auto_refresh=False, disable=disable)


def _last(iteration: int, status: str, row: dict) -> str:
    return (f"j={iteration} |e_P|={_g(row['position_error_2norm'])} m "
            f"|e_F|={_g(row['force_error_2norm'])} N {status}")


def run_one(config, method: str, path: Path, *, overwrite: bool, resume: bool, command: str):
    from ilcforce.experiment import run_method

    total = config.experiment.iterations
    with _progress_bar(disable=not err.is_terminal) as progress:
        task = progress.add_task(f"{config.experiment.name}/{method}", total=total, last="")

        def tick(record, row):
            progress.update(task, completed=record.iteration + 1, last=_last(record.iteration, record.status, row))
            progress.refresh()

        with deferred_interrupt() as interrupted:
            summary = run_method(config, method, path, overwrite=overwrite, resume=resume, command=command,
                                 progress=tick, stop_requested=interrupted)
    return summary


def run_several(config, jobs) -> None:
    """Run several methods at once, one worker process each (``ilcforce.parallel``), one display."""
    from ilcforce.parallel import run_parallel

    progress = _progress_bar(disable=not err.is_terminal)
    tasks = {}

    def tick(method: str, iteration: int, status: str, row: dict) -> None:
        if not tasks:  # the display starts after the workers were forked
            progress.start()
            tasks.update({job.method: progress.add_task(f"{config.experiment.name}/{job.method}",
                                                        total=config.experiment.iterations, last="")
                          for job in jobs})
        progress.update(tasks[method], completed=iteration + 1, last=_last(iteration, status, row))
        progress.refresh()

    def stopping() -> None:
        err.print("stopping after the current iteration is stored (again to stop now)", highlight=False)

    try:
        outcomes = run_parallel(config, jobs, progress=tick, on_interrupt=stopping, meanwhile=import_for_table)
    finally:
        progress.stop()
    failed = [o for o in outcomes.values() if o.status == "error"]
    for outcome in failed:
        if not outcome.known:
            raise RuntimeError(f"{outcome.method} failed:\n{outcome.message}")
    if failed:
        raise CliError(failed[0].message)
    if any(o.status == "interrupted" for o in outcomes.values()):
        raise KeyboardInterrupt


@contextlib.contextmanager
def deferred_interrupt():
    """First Ctrl-C or SIGTERM: stop within one chunk of the compiled loop (the iteration in flight is
    dropped, every finished one is stored). Second: stop at once.

    A KeyboardInterrupt raised wherever the signal lands (e.g. inside a garbage-collection
    callback, where Python ignores it) could be lost; a flag checked between iterations cannot.
    """
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return
    requested = list(STOPS)  # a signal whose KeyboardInterrupt Python dropped (in a GC callback) still stops

    def handler(signum, frame):
        note(signum)
        if requested:
            raise KeyboardInterrupt
        requested.append(signum)
        _say("stopping: the unfinished iteration is dropped, every finished one is stored", stderr=True)

    with on_stop_signals(handler):
        yield lambda: bool(requested)


def import_for_table() -> None:
    """What compare needs after the runs (pandas, the report's tables), imported while workers run."""
    import ilcforce.report.tables  # noqa: F401
