"""The `report`, `validate` and `version` commands: read stores, write the report, check stores. No
science here."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Optional

import typer

from ilcforce import __version__
from ilcforce.cli.base import CliError, _guard, _say, app

@app.command()
@_guard
def report(
    results: Annotated[Path, typer.Option("--results", help="folder of HDF5 stores (results/<experiment>/<method>.h5)")] = Path("results"),
    out_dir: Annotated[Optional[Path], typer.Option("--out", help="output folder, replaced whole: absent, empty or an earlier report (default: <results>/report)")] = None,
    jobs: Annotated[int, typer.Option("--jobs", "-j", help="worker processes (default: CPU count)", show_default=False)] = 0,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="no progress lines (warnings are still printed)")] = False,
    pdf: Annotated[bool, typer.Option("--pdf", help="also write every figure as PDF (vector; about doubles the drawing time)")] = False,
) -> None:
    """Write the paper's tables, figures and a verdict on each claim from the HDF5 stores."""
    from ilcforce.report.build import write_report
    from ilcforce.report.folder import ReportFolderError

    if results.exists() and not results.is_dir():
        raise CliError(f"--results {results} is a file, not a folder of stores")
    if not results.is_dir():
        raise CliError(f"results folder {results} does not exist; run `ilcforce simulate` or `make reproduce` first")
    target = out_dir if out_dir is not None else results / "report"
    if jobs < 0:
        raise CliError(f"--jobs must be >= 0 (0: one per CPU), got {jobs}")
    formats = ("png", "pdf") if pdf else ("png",)
    try:  # a folder that is not a report, or holds the results, is refused before anything is read
        summary = write_report(results, target, formats=formats, jobs=jobs or os.cpu_count() or 1,
                               progress=None if quiet else lambda text: _say(f"report: {text}", stderr=True))
    except ReportFolderError as exc:
        raise CliError(str(exc)) from None
    for warning in summary.warnings:
        _say(f"warning: {warning}", stderr=True)
    if not summary.experiments and not summary.studies and not any(
            Path(f).is_relative_to(Path(target) / "tuning") for f in summary.files):
        raise CliError(f"no usable ilcforce stores under {results}")
    done = [*summary.experiments, *(f"study {name}" for name in summary.studies)] or ["the tuning stores"]
    page = f" and {summary.html.path.name} ({summary.html.size_text()})" if summary.html is not None else ""
    _say(f"report for {', '.join(done)} written to {target}/index.md{page}")


@app.command()
@_guard
def validate(paths: Annotated[list[Path], typer.Argument(help="run, study or tuning stores to check")]) -> None:
    """Check stores: run and study stores (HDF5) against the ilcforce schema, and tuning stores
    (results/tuning/<name>/) record by record.

    Every file is checked, one line each; the exit code is 2 if any is not a valid store. The files
    ilcforce keeps beside a store (<store>.lock, a study's <store>.journal) are named and skipped, so
    `ilcforce validate results/paper/*` checks the stores.
    """
    from ilcforce import store
    from ilcforce.store.safeio import companion_of
    from ilcforce.store.study_read import DAMAGED_RECORD, StudyStoreError, check_study_store, is_study_store

    from ilcforce.store.tuning import TuningStoreError, is_tuning_store
    from ilcforce.tune.runner import validate_tuning

    invalid = 0
    for path in paths:
        companion = companion_of(path)
        if companion is not None:  # e.g. from `validate results/paper/*`: ilcforce's own, not damage
            _say(f"{path}: skipped ({companion})")
            continue
        try:
            if is_tuning_store(path):
                t = validate_tuning(path)
                counts = ", ".join(f"{m} {n} trials ({failed} failed)" for m, (n, failed, _best) in t["methods"].items())
                _say(f"{path}: ok (tuning {t['name']}: {counts})")
                continue
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
        except (store.StoreError, StudyStoreError, TuningStoreError, OSError) as exc:
            message = f"{exc.filename or path}: {exc.strerror or exc}" if isinstance(exc, OSError) else str(exc)
            _say(f"error: {message.splitlines()[0] if message else type(exc).__name__}", stderr=True)
            invalid += 1
    if invalid:
        raise typer.Exit(2)


@app.command()
def version() -> None:
    """Print the ilcforce version."""
    _say(f"ilcforce {__version__}")
