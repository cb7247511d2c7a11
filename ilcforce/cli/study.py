"""The `study` and `export` commands: parse, call ilcforce.study, render. No science here.

Registered on the CLI's ``app`` when :mod:`ilcforce.cli.main` imports this module; the heavy modules
(Dask, pandas, h5py) are imported inside the commands, so `ilcforce --help` does not load them.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce.cli.base import _command_line, _fail, _say, app, err, out
from ilcforce.stops import STOPS, announce, stop_code


def _fail_plain(message: str) -> None:
    """One line on stderr, exit 2; whitespace (a multi-line library message) folded to spaces."""
    _fail(" ".join(str(message).split()))


def _study_errors():
    from ilcforce.study import ExportError, StudyError, StudyRunError, StudyStoreError

    return (StudyError, StudyStoreError, StudyRunError, ExportError)


def eta_text(total: int, finished: int, failed: int, to_run: int, since_first: float) -> str:
    """What a progress line says of the time left. Until a cell of this run has finished: "compiling, no
    cell finished yet" (the workers' first cells include compiling the kernels, which took 12 minutes on a
    loaded machine, and an ETA from them said 27794 s); after the first, which paid for the compiling,
    the ETA waits for the next; from then on "ETA <s> s" at the pace since the first finished
    (``since_first`` seconds ago); "" when every cell is done."""
    done = finished + failed
    if done >= total:
        return ""
    ran = done - (total - to_run)
    if ran <= 0:
        return "compiling, no cell finished yet"
    if ran == 1:
        return "first cell finished (compiling included), ETA after the next"
    return f"ETA {since_first / (ran - 1) * (total - done):.0f} s"


class _StudyProgress:
    """Progress over cells: a rich bar on a terminal, a line every ~10 s otherwise; both say
    "compiling" until a cell has finished and an ETA from then on (:func:`eta_text`)."""

    def __init__(self, name: str, quiet: bool, stop: list | None = None) -> None:
        import time

        self.name, self.quiet, self._time = name, quiet, time.monotonic
        self._stop = stop if stop is not None else []  # non-empty: a stop signal came (ilcforce.stops)
        self.bar = None
        self._next_line = 0.0
        self._started = self._time()
        self._first = None  # when the first cell of this run finished

    def __enter__(self):
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        if not self.quiet and err.is_terminal:
            self.bar = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                TextColumn("cells, {task.fields[failed]} failed"), TimeElapsedColumn(),
                                TextColumn("{task.fields[eta]}"), TextColumn("{task.fields[last]}"),
                                console=err.console(), transient=False)
            self.bar.__enter__()
            self.task = None
        return self

    def __call__(self, p) -> None:
        if self._stop:  # the signal handler's KeyboardInterrupt was lost (raised inside a weakref or GC
            raise KeyboardInterrupt  # callback, Python ignores it): stop here, after a cell's commit
        if self.quiet:
            return
        now = self._time()
        if p.last == "":
            self._started, self._first = now, None
        elif self._first is None:
            self._first = now  # the first cell of this run finished: the ETA's pace is measured from here
        elapsed = now - self._started
        eta = eta_text(p.total, p.finished, p.failed, p.to_run, 0.0 if self._first is None else now - self._first)
        if self.bar is not None:
            if self.task is None:
                self.task = self.bar.add_task(self.name, total=p.total, completed=p.finished, failed=0, last="",
                                              eta=eta)
            self.bar.update(self.task, completed=p.finished + p.failed, failed=p.failed, last=p.last[:60], eta=eta)
            return
        done = p.finished + p.failed
        if p.last == "" or done == p.total or now >= self._next_line:
            self._next_line = now + 10.0
            _say(f"{self.name}: {done}/{p.total} cells, {p.failed} failed, {elapsed:.0f} s"
                 + (f", {eta}" if eta else ""), stderr=True)  # one line, never wrapped at 80 columns

    def __exit__(self, *exc):
        if self.bar is not None:
            self.bar.__exit__(*exc)


@app.command()
def study(
    ctx: typer.Context,
    files: Annotated[Optional[list[Path]], typer.Argument(help="study files: TOML whose table study holds name, seeds (\"0-9\" or a list) and optionally experiment (a file), methods, study.set (fixed values, as --set), study.sweep (a grid) or study.settings (a list); several run one after another on one cluster; none with --sweep/--seeds", show_default=False)] = None,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://HOST:8786")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", help="local worker processes (default: one per core; 1 runs in this process without Dask)")] = None,
    results: Annotated[Path, typer.Option("--results", help="results folder; the study store is <results>/studies/<name>.h5")] = Path("results"),
    resume: Annotated[bool, typer.Option("--resume", help="continue a stored study (refused if there is none); a plain rerun continues too")] = False,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="discard the stored study and run every cell again")] = False,
    replace_stale: Annotated[bool, typer.Option("--replace-stale", help="start over when the stored study has other settings or came from other simulation code, instead of refusing")] = False,
    keep_stores: Annotated[bool, typer.Option("--keep-stores", help="also write each cell's full run store under <results>/studies/<name>/cells/")] = False,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no progress output")] = False,
    timeout: Annotated[float, typer.Option("--timeout", help="seconds allowed to reach --scheduler")] = 10.0,
    sweeps: Annotated[Optional[list[str]], typer.Option("--sweep", help="instead of a study file: KEY=V1,V2,... swept (repeat for a grid); the study file it stands for is saved as <results>/studies/<name>.toml", show_default=False)] = None,
    seeds: Annotated[Optional[str], typer.Option("--seeds", help="with --sweep (or alone): the seeds, a-b or a,b,c", show_default=False)] = None,
    methods: Annotated[Optional[str], typer.Option("--methods", "-m", help="with --sweep/--seeds: comma-separated methods (default: every method)", show_default=False)] = None,
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="with --sweep/--seeds: the experiment (default: the paper's setup)", show_default=False)] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", help="with --sweep/--seeds: KEY=VALUE fixed for every cell (repeatable)", show_default=False)] = None,
) -> None:
    """Run studies (seeds x settings x methods) on Dask; finished cells are stored and never rerun."""
    from ilcforce.study import load_study, run_study
    from ilcforce.study.runner import SharedClient, check_store
    from ilcforce.tomlfile import resolve_toml

    # SIGTERM and Ctrl-C: the entry point's stops.stop_signals raise KeyboardInterrupt here
    try:
        inline = _inline_study(files, results, sweeps, seeds, methods, config, sets)  # --sweep/--seeds
        specs = [inline] if inline else [load_study(resolve_toml(file)) for file in files]  # all valid before a cell runs
        names = [spec.name for spec in specs]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            same = [str(file) for file, name in zip(files, names) if name == twice[0]]
            _fail_plain(f"two study files name the same study {twice[0]!r}: {' and '.join(same[:2])} (each is "
                        f"stored as results/studies/<name>.h5)")
        for spec in specs:  # every store usable before any cell runs
            check_store(spec, results, resume=resume, overwrite=overwrite, replace_stale=replace_stale)
        if inline:
            from ilcforce.study.options import save_study_file

            save_study_file(inline)  # beside its store, before its first cell
        with SharedClient() as shared:
            for spec in specs:
                with _StudyProgress(spec.name, quiet, STOPS) as progress:
                    summary = run_study(spec, results, workers=workers, scheduler=scheduler, resume=resume,
                                        overwrite=overwrite, replace_stale=replace_stale, keep_stores=keep_stores,
                                        command=_command_line(ctx), progress=progress, timeout=timeout,
                                        shared=shared)
                _summarise(spec, summary, quiet)
    except _study_errors() as exc:
        _fail_plain(str(exc) or type(exc).__name__)
    except OSError as exc:
        _fail_plain(f"{exc.filename or results}: {exc.strerror or exc}")
    except KeyboardInterrupt:
        _say(announce("every finished cell is stored; rerun the same command to continue"), stderr=True)
        raise typer.Exit(stop_code())


def _inline_study(files, results, sweeps, seeds, methods, config, sets):
    """The study of --sweep/--seeds/--methods/--config/--set (ilcforce.study.options), None with study files."""
    given = [flag for flag, value in (("--sweep", sweeps), ("--seeds", seeds), ("--methods", methods),
                                      ("--config", config), ("--set", sets)) if value]
    if files and given:
        _fail_plain(f"give study files or {given[0]}, not both (a study file says its own methods, seeds, sweep, "
                    "set and experiment)")
    if files:
        return None
    if not given:
        _fail_plain("give a study file, or a study by its options, e.g. `ilcforce study -m c3 --sweep c3.eta=1,2,5 "
                    "--seeds 0-19`")
    from ilcforce.cli.base import CliError, _methods
    from ilcforce.study.options import study_from_options

    try:
        names = _methods(methods) if methods is not None else None
    except CliError as exc:
        _fail_plain(str(exc))
    return study_from_options(results, methods=names, seeds=seeds, sweeps=list(sweeps or ()), sets=list(sets or ()),
                              experiment=config)


def _summarise(spec, summary, quiet: bool) -> None:
    for line in summary.quarantined:
        err.print(f"warning: {spec.name}: journal record {line}", highlight=False, markup=False, soft_wrap=True)
    for cell, message in summary.failed[:10]:
        err.print(f"warning: {spec.name}: cell {cell.method} seed {cell.seed} setting {cell.setting} failed twice: "
                  f"{message}", highlight=False, markup=False, soft_wrap=True)
    if not quiet:
        where = summary.scheduler if summary.workers == 0 else f"{summary.scheduler}, {summary.workers} worker(s)"
        where = f"on {where}" if summary.ran else "(nothing to run)"
        out.print(f"{spec.name}: {summary.total} cells ({summary.skipped} already stored, {summary.ran} run, "
                  f"{len(summary.failed)} failed) in {summary.wall_time:.1f} s {where} -> {summary.path}",
                  highlight=False, markup=False, soft_wrap=True)


@app.command()
def export(
    store_path: Annotated[Path, typer.Argument(help="a study store (results/studies/<name>.h5) or a run store")],
    out_path: Annotated[Path, typer.Option("--out", "-o", help="output table (.csv)")],
    overwrite: Annotated[bool, typer.Option("--overwrite", help="replace an existing output file")] = False,
) -> None:
    """Write a store's metrics as one tidy table: one row per (setting, seed, method, iteration)."""
    from ilcforce.study import export as export_table

    try:
        path, rows = export_table(store_path, out_path, overwrite=overwrite)
    except _study_errors() as exc:
        _fail_plain(str(exc) or type(exc).__name__)
    except OSError as exc:
        _fail_plain(f"{exc.filename or out_path}: {exc.strerror or exc}")
    from ilcforce.study.tidy import units_path

    out.print(f"{rows} rows written to {path} (units in {units_path(path)})", highlight=False, markup=False)
