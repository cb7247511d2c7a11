"""The `tune` command: ``ilcforce tune TUNING.toml`` tunes methods' gains with one budget each
(:mod:`ilcforce.tune`), then writes the tuned experiment file. No science here.

Output: a progress line per stored trial on stderr (``tune NAME: c3 trial 4/65: error -4.12, chattering
-0.31, feasible (front 3)``), then one summary line per method (its search, and the gains shipped or
withheld) and the path of the tuned experiment file on stdout.
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
    if p.state != "complete":
        said = f"failed [{p.message[:100]}]"
    else:
        said = (f"error {p.value:.4g}, chattering {p.chattering:+.3g}, "
                + ("feasible" if p.feasible else f"infeasible [{p.message[:100]}]"))
    return f"tune {name}: {p.method} trial {p.number + 1}/{p.trials}: {said} (front {p.front})"


def summary_line(name: str, method: str, search: dict, point: dict | None, axes: tuple[str, ...]) -> str:
    """One method's outcome: its search (trials, converged or not) and what it ships (its settled H on the
    task's ``axes``)."""
    from ilcforce.tune.heldout import NONE_UNDER_CAP
    from ilcforce.tune.objectives import per_axis_text
    from ilcforce.tune.search import outcome

    done = (f"{search['trials']} trials (first budget {search['first']}, at most {search['most']}), "
            + outcome(search, gain=True))
    ships = (f"ships trial {point['trial']}: held-out e_P {point['e_p']:.3g} m, e_F {point['e_f']:.3g} N, "
             f"{per_axis_text(axes, [point[f'h_{a}'] for a in axes])}" if point is not None else NONE_UNDER_CAP)
    return f"{name}: {method}: {done}; {ships}"


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
    for method in tuning.methods:
        _line(summary_line(tuning.name, method, summary.searches[method], summary.chosen.get(method), tuning.axes))
    if not quiet:
        run, planned = summary.pruned
        pruning = (f"; check runs stopped early ran {run} of {planned} iterations ({1 - run / planned:.0%} saved)"
                   if planned else "")
        _line(f"{tuning.name}: {summary.ran} trials run, {summary.skipped} already stored, in "
              f"{summary.wall_time:.1f} s on {summary.scheduler}{pruning} -> {summary.path}")
    if summary.tuned is None:
        _line(f"error: {tuning.name}: no method has stable gains under the cap; no tuned experiment file "
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
