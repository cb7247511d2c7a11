"""The report's pieces that run as pool tasks (:mod:`ilcforce.report.pool`) beside the experiments:
a study's report, a study's findings page, and what each piece is expected to cost, so that the
heaviest start first and neither core idles at the end."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ilcforce.report import study_findings
from ilcforce.report.figure_files import ReportWriteError


def experiment_cost(paths) -> float:
    """Rough seconds an experiment's report takes: validating and drawing grow with its stores' bytes."""
    total = 0
    for path in paths:
        try:
            total += Path(path).stat().st_size
        except OSError:
            pass
    return 5.0 + 0.03 * total / 1e6


def study_cost(path: Path, per_setting: float) -> float:
    """Rough seconds a study's report (or findings page) takes: figures and claims per setting."""
    from ilcforce.store.study_read import StudyStoreError, read_header

    try:
        settings = len(read_header(path)["settings"])
    except (StudyStoreError, OSError, KeyError, TypeError):
        settings = 1
    return per_setting * (1 + settings)


def study_report(path: Path, out_dir: Path, formats: tuple[str, ...],
                 progress: Callable[[str], None] | None = None):
    """One study's report (a pool task): a :class:`ilcforce.report.study.StudyReport`."""
    from ilcforce.report.figures import report_style
    from ilcforce.report.study import write_study_report

    with report_style():
        return write_study_report(path, out_dir, formats=formats, progress=progress)


def study_findings_page(path: Path, out_dir: Path, progress: Callable[[str], None] | None = None):
    """One study's findings page (a pool task): (files, name, findings), or a warning line."""
    try:
        return study_findings.write_study_findings(path, out_dir)
    except ReportWriteError:  # a full disk ends the report; a bad store does not
        raise
    except Exception as error:  # one bad study store never aborts the report  # noqa: BLE001
        return f"{path}: study findings not written: {' '.join(str(error).split())}"
