"""Command-line interface: parse, call one library function, render. No science here.

Exit codes: 0 success (a diverged method is a result, not a failure), 2 bad input or a store that
cannot be used (one line on stderr, never a traceback), 130 interrupted (Ctrl-C), 143 terminated
(SIGTERM, which takes Ctrl-C's path: :mod:`ilcforce.cli_signals`).
"""

from __future__ import annotations

import functools
import os
import math
import shlex
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce import __version__
from ilcforce.cli_signals import announce, stop_code
from ilcforce.controllers import PAPER_METHODS, REGISTRY

# Only what every command needs is imported here: `ilcforce --help` and one-line input errors must
# not pay for rich's consoles and tables, pandas, numba's kernels, h5py or matplotlib (issue 12;
# `python -X importtime -m ilcforce --help` shows what is left). Commands import what they use.


class _LazyConsole:
    """A rich ``Console`` made on first use; ``out.print(...)`` and ``err.print(...)`` as usual."""

    def __init__(self, stderr: bool) -> None:
        self._stderr = stderr
        self._console = None

    def console(self):
        """The rich ``Console`` itself (for rich objects that take one)."""
        if self._console is None:
            from rich.console import Console

            self._console = Console(stderr=self._stderr)
        return self._console

    def __getattr__(self, name: str):
        return getattr(self.console(), name)

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    help="Iterative learning control for hybrid force/position control of robot manipulators in contact "
         "(five-bar and serial 2R; reproduces and checks the ILC + sliding mode paper; see README.md).",
)
out = _LazyConsole(stderr=False)
err = _LazyConsole(stderr=True)


class CliError(Exception):
    """Bad input found by the CLI itself."""


def _say(text: str, *, stderr: bool = False) -> None:
    """One plain line: never markup, never wrapped, never a UnicodeEncodeError (unencodable
    characters are replaced under an ASCII locale)."""
    stream = sys.stderr if stderr else sys.stdout
    encoding = getattr(stream, "encoding", None) or "utf-8"
    line = " ".join(str(text).split()) if "\n" in str(text) else str(text)
    try:
        stream.write(line.encode(encoding, "replace").decode(encoding, "replace") + "\n")
        stream.flush()
    except (OSError, ValueError):
        pass


def _fail(message: str, code: int = 2) -> None:
    _say(f"error: {message}", stderr=True)
    raise typer.Exit(code)


#: What each command says after "interrupted: " or "terminated (SIGTERM): " when a stop signal ends it.
_ON_STOP = {"simulate": "every finished iteration is stored; continue with --resume",
            "compare": "every finished iteration is stored; run the same command to continue",
            "report": "the report was not finished; run `ilcforce report` again",
            "validate": "nothing was changed"}


def _guard(func):
    """Turn the library's input errors into one line and exit code 2, and a stop signal (Ctrl-C,
    SIGTERM) into one line and exit code 130 or 143."""

    @functools.wraps(func)
    def wrapper(*args, **kwargs):
        try:
            from ilcforce.config import ConfigError
            from ilcforce.experiment import UnknownMethodError
            from ilcforce.store import StoreError

            try:
                return func(*args, **kwargs)
            except (ConfigError, StoreError, UnknownMethodError, CliError) as exc:
                _fail(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            except OSError as exc:
                _fail(f"{exc.filename or ''}: {exc.strerror or exc}".lstrip(": "))
            except MemoryError as exc:  # numpy's says what it could not allocate
                _fail(f"out of memory: {exc}".rstrip(": ") + " (every finished iteration is stored)"
                      if func.__name__ in ("simulate", "compare") else f"out of memory: {exc}".rstrip(": "))
        except KeyboardInterrupt:
            _say(announce(_ON_STOP.get(func.__name__, "stopped")), stderr=True)
            raise typer.Exit(stop_code())

    return wrapper


def _load(config: Optional[Path], seed: Optional[int], iters: Optional[int], sets: Optional[list[str]]):
    from ilcforce.compile_note import announce_compiles

    # a first run compiles before iteration 0: say so on a terminal (ilcforce/compile_note.py). Whether
    # stderr is one is asked only then: the check builds a rich Console (issue 12: not before the run)
    announce_compiles(lambda text: _say(text, stderr=True) if err.is_terminal else None)
    from ilcforce.config_load import command_overrides, load_config

    return load_config(config, command_overrides(sets, seed, iters))


def _variant(seed: Optional[int], sets: Optional[list[str]]) -> dict[str, object]:
    """The overrides that make a variant (its own results folder): every --set, and --seed."""
    from ilcforce.config_load import command_overrides

    return command_overrides(sets, seed)


def _methods(text: str) -> list[str]:
    names = [m.strip().lower() for m in text.split(",") if m.strip()]
    if not names:
        raise CliError("--methods is empty; e.g. --methods c1,c2,c3")
    for name in names:
        if name not in REGISTRY:
            raise CliError(f"unknown method {name!r}; choose from {', '.join(REGISTRY)}")
    return names


def _g(value) -> str:
    """A table cell: 3 significant digits, '-' for a missing value (None, NaN, pandas NA)."""
    if value is None or type(value).__name__ == "NAType":  # pandas.NA, without importing pandas
        return "-"
    if isinstance(value, float):
        return "-" if math.isnan(value) else f"{value:.3g}"
    return str(value)


def _command_line(ctx: typer.Context) -> str:
    """The invocation as ilcforce saw it (resolved options), for the store's provenance."""
    parts = ["ilcforce", ctx.info_name or ""]
    flags = {"out_path": "--out", "out_dir": "--out", "sets": "--set"}
    positional = {p.name for p in ctx.command.params if p.param_type_name == "argument"}
    for name, value in ctx.params.items():
        if value in (None, False, [], ()):
            continue
        flag = flags.get(name, "--" + name.replace("_", "-"))
        values = value if isinstance(value, (list, tuple)) else [value]
        for v in values:
            parts += [str(v)] if name in positional else [flag] if v is True else [flag, str(v)]
    return shlex.join(parts)


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
    from ilcforce import cli_run
    from ilcforce.experiment import default_store_path

    names = _methods(method)
    if len(names) != 1:
        raise CliError("--method takes one method; use `ilcforce compare --methods ...` for several")
    cfg = _load(config, seed, iters, sets)
    path = out_path if out_path is not None else default_store_path(results, cfg, names[0], _variant(seed, sets))
    summary = cli_run.run_one(cfg, names[0], path, overwrite=overwrite, resume=resume, command=_command_line(ctx))
    table = _table(f"{cfg.experiment.name} / {names[0]}  ->  {path}")
    for col in ("j", "|e_P|_2 (m)", "|e_F|_2 (N)", "H_x (N)", "H_y (N)", "loop fallbacks", "status"):
        table.add_column(col, justify="right")
    for row in summary.rows:
        status = row["status"] if row["status"] == "complete" else (f"diverged at t = {row['diverged_time']:.4f} s", "red")
        table.add_row(str(row["iteration"]), _g(row["position_error_2norm"]), _g(row["force_error_2norm"]),
                      _g(row["chattering_task_x"]), _g(row["chattering_task_y"]), str(row["fallback_count"]), status)
    if summary.rows:
        table.print(out.console())
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
    from ilcforce import cli_run, store
    from ilcforce.experiment import default_store_path
    from ilcforce.parallel import Job

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
        cli_run.run_one(cfg, job.method, job.path, overwrite=job.overwrite, resume=job.resume, command=job.command)
    elif jobs:
        cli_run.run_several(cfg, jobs)

    from ilcforce.comparison import MethodMetrics, comparison_rows

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


def _table(title: str):
    """A table whose title is shown literally (a path may contain [brackets]), drawn as rich draws
    its tables (:mod:`ilcforce.cli_table`); ASCII borders when the output encoding cannot show
    box-drawing characters."""
    from ilcforce.cli_table import Table

    encoding = (out.encoding or "").lower().replace("-", "")
    shown = title.encode(out.encoding or "utf-8", "replace").decode(out.encoding or "utf-8", "replace")
    return Table(shown, ascii_box=not encoding.startswith("utf"))


def _compare_action(cfg, method: str, path: Path, overwrite: bool) -> tuple[str, bool]:
    """("keep" | "resume" | "run", replace?) for one method's store, by the same-run policy."""
    from ilcforce import samerun, store

    if not path.exists() and not path.is_symlink():
        return "run", False
    provenance = store.read_provenance(path)
    if str(provenance.get("method", method)) != method:  # e.g. another method's store copied here
        if not overwrite:
            raise CliError(f"{path} holds a {provenance.get('method')} run, not {method}; move it away or "
                           "pass --overwrite to rerun it")
        return "run", True
    keys = samerun.differences(samerun.stored_config(provenance), cfg.to_dict(), method)
    if keys:
        if not overwrite:
            raise CliError(f"{path} holds a {method} run with a different configuration: "
                           f"{samerun.describe(samerun.stored_config(provenance), cfg.to_dict(), keys)}; "
                           "pass --overwrite to rerun it")
        return "run", True
    done = store.iterations(path)
    finished = provenance.get("run_state") == "diverged" or (
        provenance.get("run_state") == "complete" and len(done) >= cfg.experiment.iterations)
    return ("keep" if finished else "resume"), False


def _print_comparison(rows: list[dict], title: str) -> None:
    """One row per quantity, one column per method (narrow enough for a terminal)."""
    from ilcforce.comparison import COMPARISON_COLUMNS

    table = _table(title)
    table.add_column("")
    for row in rows:
        table.add_column(str(row["method"]), justify="right")
    for name, unit in COMPARISON_COLUMNS.items():
        if name == "method":
            continue
        label = f"{name} ({unit})" if unit not in ("", "-") else name
        table.add_row(label, *(_g(row[name]) for row in rows))
    table.print(out.console())


@app.command()
@_guard
def report(
    results: Annotated[Path, typer.Option("--results", help="folder of HDF5 stores (results/<experiment>/<method>.h5)")] = Path("results"),
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="output folder (default: <results>/report)")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="worker processes (default: CPU count)", show_default=False)] = 0,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no progress lines (warnings are still printed)")] = False,
    pdf: Annotated[bool, typer.Option("--pdf", help="also write every figure as PDF (vector; about doubles the drawing time)")] = False,
) -> None:
    """Write the paper's tables, figures and a verdict on each claim from the HDF5 stores."""
    from ilcforce.report.build import write_report

    if results.exists() and not results.is_dir():
        raise CliError(f"--results {results} is a file, not a folder of stores")
    if not results.is_dir():
        raise CliError(f"results folder {results} does not exist; run `ilcforce simulate` or `make reproduce` first")
    target = out_dir if out_dir is not None else results / "report"
    if target.exists() and not target.is_dir():
        raise CliError(f"--out {target} is a file, not a folder; the report is a folder (index.md and one folder "
                       "per experiment)")
    if jobs < 0:
        raise CliError(f"--jobs must be >= 0 (0: one per CPU), got {jobs}")
    formats = ("png", "pdf") if pdf else ("png",)
    summary = write_report(results, target, formats=formats, jobs=jobs or os.cpu_count() or 1,
                           progress=None if quiet else lambda text: _say(f"report: {text}", stderr=True))
    for warning in summary.warnings:
        _say(f"warning: {warning}", stderr=True)
    if not summary.experiments and not summary.studies:
        raise CliError(f"no usable ilcforce stores under {results}")
    done = [*summary.experiments, *(f"study {name}" for name in summary.studies)]
    _say(f"report for {', '.join(done)} written to {target}/index.md")


@app.command()
@_guard
def validate(paths: Annotated[list[Path], typer.Argument(help="run or study stores to check")]) -> None:
    """Check HDF5 stores against the ilcforce schema: run stores and study stores (results/studies).

    Every file is checked, one line each; the exit code is 2 if any is not a valid store. The files
    ilcforce keeps beside a store (<store>.lock, a study's <store>.journal) are named and skipped, so
    `ilcforce validate results/paper/*` checks the stores.
    """
    from ilcforce import store
    from ilcforce.store.safeio import companion_of
    from ilcforce.store.study_read import DAMAGED_RECORD, StudyStoreError, check_study_store, is_study_store

    invalid = 0
    for path in paths:
        companion = companion_of(path)
        if companion is not None:  # e.g. from `validate results/paper/*`: ilcforce's own, not damage
            _say(f"{path}: skipped ({companion})")
            continue
        try:
            if is_study_store(path):
                s = check_study_store(path)
                ignored = (f"; {len(s['ignored'])} journal entries ignored ({', '.join(s['ignored'][:3])}"
                           f"{', ...' if len(s['ignored']) > 3 else ''})" if s["ignored"] else "")
                if any(DAMAGED_RECORD in entry for entry in s["ignored"]):
                    ignored += "; a damaged record's cell runs again on the next study run"
                _say(f"{path}: ok (study {s['name']}, {s['cells']} cells: {s['done']} done, {s['failed']} failed)"
                     + ignored + "".join(f"; {n}" for n in s.get("notes", ())))
                continue
            notes = store.validate(path) or []
            prov = store.read_provenance(path)
            _say(f"{path}: ok ({prov.get('experiment')}/{prov.get('method')}, "
                 f"{len(store.iterations(path))} iterations, {prov.get('run_state')})" + "".join(f"; {n}" for n in notes))
        except (store.StoreError, StudyStoreError, OSError) as exc:
            message = f"{exc.filename or path}: {exc.strerror or exc}" if isinstance(exc, OSError) else str(exc)
            _say(f"error: {message.splitlines()[0] if message else type(exc).__name__}", stderr=True)
            invalid += 1
    if invalid:
        raise typer.Exit(2)


@app.command()
def version() -> None:
    """Print the ilcforce version."""
    _say(f"ilcforce {__version__}")


# the `study`, `export` and `config` commands (registered on `app` when their module is imported)
from ilcforce import cli_config, cli_study  # noqa: E402,F401

# the command runner the console entry point calls (pyproject: ilcforce._entry:main), in its own module
from ilcforce.cli_main import main  # noqa: E402,F401


if __name__ == "__main__":
    main()
