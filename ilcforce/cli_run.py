"""Running methods from the CLI: one live display over a run (or over parallel runs, one per
method, ``ilcforce.parallel``), and Ctrl-C handled so that every finished iteration is stored.

Used by ``simulate`` and ``compare`` in :mod:`ilcforce.cli`; no science here either.
"""

from __future__ import annotations

import contextlib
import threading
from pathlib import Path

from ilcforce import interrupts
from ilcforce.cli import CliError, _g, _say, err  # imported by cli's commands, once cli is loaded
from ilcforce.cli_signals import STOPS, note, on_stop_signals


class _Display:
    """The run's live display (rich), made at its first update, i.e. after iteration 0 is stored.

    Neither rich nor the terminal check (which builds a rich Console) comes before the simulation
    has started: both are imported while the compiled loop runs (issue 12). Off a terminal nothing
    is drawn. The summary table's modules are imported at that first update too, for the same reason.
    """

    def __init__(self, names: list[str], total: int) -> None:
        self._names, self._total = names, total  # one line per name, in this order
        self._progress = None
        self._tasks: dict[str, object] = {}
        self._off = False

    def update(self, name: str, completed: int, last: str) -> None:
        if self._off:
            return
        if self._progress is None:
            import rich.table  # noqa: F401 - the summary table, later

            if not err.is_terminal:
                self._off = True
                return
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

            # no refresh thread: the display is redrawn at each update (and so nothing runs while compare forks)
            self._progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                      TextColumn("{task.fields[last]}"), TimeElapsedColumn(), console=err.console(),
                                      transient=False, auto_refresh=False)
            self._progress.start()
            self._tasks = {n: self._progress.add_task(n, total=self._total, last="") for n in self._names}
        self._progress.update(self._tasks[name], completed=completed, last=last)
        self._progress.refresh()

    def say(self, text: str) -> None:
        """One line on stderr, above the display if it is drawn. Safe in a signal handler that
        interrupted the display's own first update (rich half imported): a plain line then."""
        if self._progress is not None:
            self._progress.console.print(text, highlight=False, markup=False)
        else:
            _say(text, stderr=True)

    def stop(self) -> None:
        if self._progress is not None:
            self._progress.stop()


def _last(iteration: int, status: str, row: dict) -> str:
    return (f"j={iteration} |e_P|={_g(row['position_error_2norm'])} m "
            f"|e_F|={_g(row['force_error_2norm'])} N {status}")


def run_one(config, method: str, path: Path, *, overwrite: bool, resume: bool, command: str):
    from ilcforce import early_start
    from ilcforce.experiment import run_method

    started = early_start.take(config, method, resume=resume)  # begun while typer loaded, if it could be

    name = f"{config.experiment.name}/{method}"
    display = _Display([name], config.experiment.iterations)

    def tick(record, row):
        display.update(name, record.iteration + 1, _last(record.iteration, record.status, row))

    try:
        with deferred_interrupt() as interrupted:
            return run_method(config, method, path, overwrite=overwrite, resume=resume, command=command,
                              progress=tick, stop_requested=interrupted, started=started)
    finally:
        display.stop()


def run_several(config, jobs) -> None:
    """Run several methods at once, one worker process each (``ilcforce.parallel``), one display."""
    from ilcforce.parallel import run_parallel

    display = _Display([f"{config.experiment.name}/{job.method}" for job in jobs], config.experiment.iterations)

    def tick(method: str, iteration: int, status: str, row: dict) -> None:  # after the workers were forked
        display.update(f"{config.experiment.name}/{method}", iteration + 1, _last(iteration, status, row))

    def stopping() -> None:
        display.say("stopping after the current iteration is stored (again to stop now)")

    try:
        outcomes = run_parallel(config, jobs, progress=tick, on_interrupt=stopping, meanwhile=import_for_table)
    finally:
        display.stop()
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
            interrupts.interrupt()  # at once, or when the store's commit in progress has ended
            return
        requested.append(signum)
        _say("stopping: the unfinished iteration is dropped, every finished one is stored", stderr=True)

    with on_stop_signals(handler):
        yield lambda: bool(requested)


def import_for_table() -> None:
    """What compare needs after the runs (the comparison, rich's table), imported while workers run."""
    import rich.table  # noqa: F401

    import ilcforce.comparison  # noqa: F401
