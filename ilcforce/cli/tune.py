"""The `tune` command: ``ilcforce tune TUNING.toml`` tunes methods' gains with one budget each
(:mod:`ilcforce.tune`), then writes the tuned experiment file. No science here.

Output: a progress line per stored trial on stderr (``tune NAME: c3 trial 4/30: 1.234 (best 0.98,
trial 2)``), then one summary line per method and the path of the tuned experiment file on stdout.
Every error is one line on stderr, exit 2; an interrupt stores every finished trial and exits 130.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce.cli.base import _command_line, app


def _line(text: str, *, stderr: bool = False) -> None:
    stream = sys.stderr if stderr else sys.stdout
    stream.write(" ".join(str(text).split()) + "\n")
    stream.flush()


def _shown(value: float | None) -> str:
    return "failed" if value is None else f"{value:.4g}"


def progress_line(name: str, p) -> str:
    """One progress line for a stored trial (:class:`~ilcforce.tune.runner.TuneProgress`)."""
    best = f"best {_shown(p.best_value)}, trial {p.best_number}" if p.best_number is not None else "no trial complete yet"
    why = f" [{p.message[:100]}]" if p.state != "complete" and p.message else ""
    return f"tune {name}: {p.method} trial {p.number + 1}/{p.trials}: {_shown(p.value)}{why} ({best})"


def tune_command(file: Path | str, *, scheduler: str | None = None, workers: int | None = None,
                 results: Path | str = "results", overwrite: bool = False, output: Path | str | None = None,
                 quiet: bool = False, timeout: float = 10.0, command: str = "") -> int:
    """Run the tuning file ``file``; returns the exit code (0; 1 when no method could be tuned; 2 for
    any error; 130 or 143 when a stop signal ends it)."""
    from ilcforce.stops import announce, stop_code
    from ilcforce.study.dask_run import StudyRunError
    from ilcforce.tune.runner import run_tuning
    from ilcforce.tune.spec import TuneError, load_tuning
    from ilcforce.store.tuning import TuningStoreError
    from ilcforce.tomlfile import resolve_toml

    try:
        tuning = load_tuning(resolve_toml(file))  # a shipped tuning file by its bare name
        summary = run_tuning(tuning, results, workers=workers, scheduler=scheduler, overwrite=overwrite,
                             timeout=timeout, command=command, output=Path(output) if output else None,
                             progress=None if quiet else lambda p: _line(progress_line(tuning.name, p), stderr=True))
    except (TuneError, TuningStoreError, StudyRunError) as exc:
        _line(f"error: {exc}", stderr=True)
        return 2
    except OSError as exc:
        _line(f"error: {exc.filename or results}: {exc.strerror or exc}", stderr=True)
        return 2
    except KeyboardInterrupt:
        _line(announce("every finished trial is stored; rerun the same command to continue"), stderr=True)
        return stop_code()
    for line in summary.quarantined:
        _line(f"warning: {line}", stderr=True)
    for method, best in summary.best.items():
        stored = f"{summary.stored[method]} stored (budget {tuning.trials})"
        if best is None:
            _line(f"{tuning.name}: {method}: every one of its {stored} trials failed: left untuned")
        else:
            _line(f"{tuning.name}: {method}: best trial {best[0]} of {stored}, objective {best[1]:.4g}")
    if not quiet:
        _line(f"{tuning.name}: {summary.ran} trials run, {summary.skipped} already stored, in "
              f"{summary.wall_time:.1f} s on {summary.scheduler} -> {summary.path}")
    if summary.tuned is None:
        _line(f"error: {tuning.name}: no method could be tuned (every trial failed); no tuned experiment file "
              "written", stderr=True)
        return 1
    _line(f"{tuning.name}: tuned experiment file {summary.tuned} (run it with `ilcforce simulate -c {summary.tuned}`)")
    return 0


@app.command()
def tune(
    ctx: typer.Context,
    file: Annotated[Path, typer.Argument(help="tuning file: TOML with a \\[tune] table (experiment, methods, gain ranges, seeds, objective, trials)")],
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="address of an existing Dask scheduler, e.g. tcp://HOST:8786")] = None,
    workers: Annotated[Optional[int], typer.Option("--workers", help="local worker processes (default: one per core; 1 runs in this process)")] = None,
    results: Annotated[Path, typer.Option("--results", help="results folder; the tuning store is <results>/tuning/<name>/")] = Path("results"),
    overwrite: Annotated[bool, typer.Option("--overwrite", help="discard the stored trials and start over; also replace an existing --output file")] = False,
    output: Annotated[Optional[Path], typer.Option("--output", "-o", help="also write the tuned experiment file here")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no progress lines")] = False,
    timeout: Annotated[float, typer.Option("--timeout", help="seconds allowed to reach --scheduler")] = 10.0,
) -> None:
    """Tune methods' gains with Optuna on Dask (equal budget per method); finished trials are stored and never rerun."""
    raise typer.Exit(tune_command(file, scheduler=scheduler, workers=workers, results=results, overwrite=overwrite,
                                  output=output, quiet=quiet, timeout=timeout, command=_command_line(ctx)))
