"""The `simulate` and `compare` commands: run methods over the iterations, with one live display over a
run (or over parallel runs, one worker process per method: :mod:`ilcforce.cli.workers`), Ctrl-C
handled so that every finished iteration is stored, then a table of the results. No science here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce import stops
from ilcforce.cli.base import (CliError, _command_line, _g, _guard, _load, _methods, _say, _variant, app, err, fits,
                               out, show, table)
from ilcforce.controllers import PAPER_METHODS, REGISTRY

@app.command()
@_guard
def simulate(
    ctx: typer.Context,
    method: Annotated[str, typer.Option("--method", "-m", help=f"controller: {', '.join(REGISTRY)}")] = "c3",
    iters: Annotated[Optional[int], typer.Option("--iters", "-n", help="number of iterations (default: the experiment's)")] = None,
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="experiment TOML (default: the paper's setup)")] = None,
    out_path: Annotated[Optional[Path], typer.Option("--out", "-o", help="HDF5 store (default: results/<experiment>/<method>.h5)")] = None,
    seed: Annotated[Optional[int], typer.Option("--seed", help="random seed (disturbance and noise)")] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", help="override a config value, e.g. --set c3.eta=2 (repeatable)")] = None,
    overwrite: Annotated[bool, typer.Option("--overwrite", help="replace an existing result")] = False,
    resume: Annotated[bool, typer.Option("--resume", help="continue an interrupted run from its last complete iteration")] = False,
    results: Annotated[Path, typer.Option("--results", help="results folder for the default --out")] = Path("results"),
) -> None:
    """Run one method over the iterations and store every iteration in HDF5."""
    from ilcforce.experiment import default_store_path

    names = _methods(method)
    if len(names) != 1:
        raise CliError("--method takes one method; use `ilcforce compare --methods ...` for several")
    cfg = _load(config, seed, iters, sets)
    path = out_path if out_path is not None else default_store_path(results, cfg, names[0], _variant(seed, sets))
    summary = run_one(cfg, names[0], path, overwrite=overwrite, resume=resume, command=_command_line(ctx))
    from rich.text import Text

    grid = table(f"{cfg.experiment.name} / {names[0]}  ->  {path}")
    from ilcforce.metrics import columns_dimension
    from ilcforce.records import task_axes

    axes = task_axes(columns_dimension(summary.rows[0]) if summary.rows else 2)  # H per task axis: x, y or u, v, n
    for col in ("j", "|e_P|_2 (m)", "|e_F|_2 (N)", *(f"H_{axis} (N)" for axis in axes), "loop fallbacks", "status"):
        grid.add_column(col, justify="right", no_wrap=True)
    for row in summary.rows:
        status = row["status"] if row["status"] == "complete" else Text(f"diverged at t = {row['diverged_time']:.4f} s", "red")
        grid.add_row(str(row["iteration"]), _g(row["position_error_2norm"]), _g(row["force_error_2norm"]),
                      *(_g(row[f"chattering_task_{axis}"]) for axis in axes), str(row["fallback_count"]), status)
    if summary.rows:
        show(grid)
    else:
        _say(f"nothing to run: {path} already holds iterations 0..{summary.first_iteration - 1}")
    if summary.diverged:
        _say(f"{names[0]} diverged; later iterations were not run (the store records where).")


@app.command()
@_guard
def compare(
    ctx: typer.Context,
    methods: Annotated[str, typer.Option("--methods", help=f"comma-separated methods from {', '.join(REGISTRY)}")] = ",".join(PAPER_METHODS),
    config: Annotated[Optional[Path], typer.Option("--config", "-c", help="experiment TOML (default: the paper's setup)")] = None,
    iters: Annotated[Optional[int], typer.Option("--iters", "-n", help="number of iterations")] = None,
    seed: Annotated[Optional[int], typer.Option("--seed", help="random seed")] = None,
    sets: Annotated[Optional[list[str]], typer.Option("--set", help="override a config value (repeatable)")] = None,
    results: Annotated[Path, typer.Option("--results", help="results folder")] = Path("results"),
    overwrite: Annotated[bool, typer.Option("--overwrite", help="rerun methods whose stored result differs")] = False,
) -> None:
    """Run the methods that have no complete result for this experiment, then compare them side by side.

    Methods that need running run at once, one worker process each, sharing the cores.
    """
    from ilcforce import store
    from ilcforce.experiment import default_store_path
    from ilcforce.cli.workers import Job

    names = _methods(methods)
    cfg = _load(config, seed, iters, sets)
    paths = {name: default_store_path(results, cfg, name, _variant(seed, sets)) for name in names}
    jobs = []
    for name, path in paths.items():
        action, replace = _compare_action(cfg, name, path, overwrite)
        if action != "keep":
            jobs.append(Job(name, path, overwrite=replace, resume=action == "resume", command=_command_line(ctx)))
    if len(jobs) == 1:
        job = jobs[0]
        run_one(cfg, job.method, job.path, overwrite=job.overwrite, resume=job.resume, command=job.command)
    elif jobs:
        run_several(cfg, jobs)

    from ilcforce.report.comparison import MethodMetrics, comparison_rows

    # a store may hold more iterations than asked for (the first ones are the same run): the table,
    # like its title, is over the experiment's iterations
    n = cfg.experiment.iterations
    rows = comparison_rows({name: MethodMetrics.from_rows({j: row for j, row in store.read_metrics_rows(path).items()
                                                           if j < n})
                            for name, path in paths.items()})
    _print_comparison(rows, f"{_comparison_title(cfg)}  ->  {paths[names[0]].parent}")


def _comparison_title(cfg) -> str:
    """The experiment's own name and description (not boilerplate), and the seed every method shared."""
    exp = cfg.experiment
    return f"{exp.name}: {exp.description} (seed {exp.seed}, {exp.iterations} iterations)"


def _compare_action(cfg, method: str, path: Path, overwrite: bool) -> tuple[str, bool]:
    """("keep" | "resume" | "run", replace?) for one method's store, by the same-run policy."""
    from ilcforce.experiment import stored_run

    found = stored_run(cfg, method, path)
    if found.state in ("other method", "different run"):
        if not overwrite:
            raise CliError(f"{path} holds {found.detail}; move it away or pass --overwrite to rerun it"
                           if found.state == "other method" else
                           f"{path} holds a {method} run with a different configuration: {found.detail}; "
                           "pass --overwrite to rerun it")
        return "run", True
    return {"absent": "run", "partial": "resume", "finished": "keep"}[found.state], False


def _print_comparison(rows: list[dict], title: str) -> None:
    """One row per quantity, one column per method. Where the methods do not fit the output's width
    (:func:`~ilcforce.cli.base.fits`), they are shown in as many tables as it takes, each with the
    row labels: a number is never split across lines."""
    from ilcforce.report.comparison import comparison_columns

    n = 3 if rows and "chattering_task_u" in rows[0] else 2  # the task's axes: one H row each
    quantities = [(name, f"{name} ({unit})" if unit not in ("", "-", "1") else name)
                  for name, unit in comparison_columns(n).items() if name != "method"]
    cells = [[_g(row[name]) for name, _ in quantities] for row in rows]
    label_width = max(len(label) for _, label in quantities)
    widths = [max(len(str(row["method"])), *(len(c) for c in col)) for row, col in zip(rows, cells)]
    console = out.console()
    room = fits(console) - label_width - 4  # the label column and the outer borders
    groups: list[list[int]] = [[]]
    used = 0
    for i, width in enumerate(widths):
        if groups[-1] and used + width + 3 > room:
            groups.append([])
            used = 0
        groups[-1].append(i)
        used += width + 3
    for number, group in enumerate(groups):
        part = f" ({number + 1}/{len(groups)})" if len(groups) > 1 else ""
        grid = table(title + part if number == 0 else f"... {part.strip()}", console)
        grid.add_column("", no_wrap=True)
        for i in group:
            grid.add_column(str(rows[i]["method"]), justify="right", no_wrap=True)
        for k, (_, label) in enumerate(quantities):
            grid.add_row(label, *(cells[i][k] for i in group))
        show(grid, console)


class _Display:
    """The run's live display (rich), made at its first update, i.e. after iteration 0 is stored.

    Neither rich nor the terminal check (which builds a rich Console) comes before the simulation
    has started: both are imported while the compiled loop runs . Off a terminal nothing
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
    from ilcforce.experiment import run_method

    name = f"{config.experiment.name}/{method}"
    display = _Display([name], config.experiment.iterations)

    def tick(record, row):
        display.update(name, record.iteration + 1, _last(record.iteration, record.status, row))

    try:
        with deferred_interrupt() as interrupted:
            return run_method(config, method, path, overwrite=overwrite, resume=resume, command=command,
                              progress=tick, stop_requested=interrupted)
    finally:
        display.stop()


def run_several(config, jobs) -> None:
    """Run several methods at once, one worker process each (:mod:`ilcforce.cli.workers`), one display."""
    from ilcforce.cli.workers import run_parallel

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


def deferred_interrupt():
    """First Ctrl-C or SIGTERM: stop within one chunk of the compiled loop (the iteration in flight is
    dropped, every finished one is stored). Second: stop at once."""
    return stops.deferred(lambda text: _say(text, stderr=True))


def import_for_table() -> None:
    """What compare needs after the runs (the comparison, rich's table), imported while workers run."""
    import rich.table  # noqa: F401

    import ilcforce.report.comparison  # noqa: F401
