"""Write the report: tables, claims, figures and a readable ``report.md`` per experiment.

Reads only the results store (:mod:`ilcforce.store`); never simulates. Layout written::

    <out_dir>/index.md                      links to every experiment's report
    <out_dir>/findings.md                   the README's findings, written from the two tables below
    <out_dir>/claims.csv, stability.csv     every verdict of every experiment and study as rows
    <out_dir>/<experiment>/report.md        readable on its own
    <out_dir>/<experiment>/table2.csv|.md   Table 2, ours beside the paper's
    <out_dir>/<experiment>/table3.csv|.md   Table 3, ours beside the paper's
    <out_dir>/<experiment>/comparison.csv|.md
    <out_dir>/<experiment>/claims.md        the five claims with verdicts, per-part verdicts and rules
    <out_dir>/<experiment>/claims.csv       the verdicts as data (ilcforce.report.verdicts), one row per
                                            claim and per part; claim_parts.csv the full per-part frame
    <out_dir>/<experiment>/stability.csv    the learning-stability rates and flags as data
    <out_dir>/<experiment>/<figure>.png (and .pdf with formats=FIGURE_FORMATS, ilcforce report --pdf)
    <out_dir>/studies/<study>/, <out_dir>/tuning/<tuning>/   each study's and tuning's pages
    <out_dir>/long-run/long-run.md          make long's pages: from its studies when stored, else the
                                            committed ones (docs/long-run/) copied in
    <out_dir>/index.html, <out_dir>/<part>/index.html   the HTML site (ilcforce.report.html): a front
                                            page and a page per study, experiment, tuning, the long runs

Problems with the inputs (an unreadable or foreign file, a missing method, a partial run, a newer
schema) never raise: each becomes one line in :attr:`ReportSummary.warnings` and in the report,
and everything that can still be reported is.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ilcforce import __version__, store
from ilcforce.report import claims as claims_module
from ilcforce import stability
from ilcforce.report import html, long_run, paper, pool, readme, sections, table_write, tables, tasks
from ilcforce.report import folder as report_folder
from ilcforce.report import verdicts as verdict_rows
from ilcforce.store.schema import RESERVED_NAMES
from ilcforce.report.figure_files import write_text_whole
from ilcforce.report.index_page import index_text
from ilcforce.report.study import count_text
from ilcforce.report.run_figures import DEFAULT_FORMATS, FIGURE_FORMATS, FIGURES, READ_ERRORS as _READ_ERRORS
from ilcforce.report.run_figures import write_figures as _write_figures
from ilcforce.report.run_text import divergence_lines as _divergence_lines
from ilcforce.report.run_text import report_text as _report_text
from ilcforce.report.run_text import tidy_metrics

__all__ = ["DEFAULT_FORMATS", "EXPECTED_METHODS", "FIGURES", "FIGURE_FORMATS", "ReportSummary", "tidy_metrics", "write_report"]

#: The methods an experiment is expected to hold.
EXPECTED_METHODS = tables.METHOD_ORDER


@dataclass(frozen=True)
class ReportSummary:
    """What :func:`write_report` did.

    Attributes
    ----------
    out_dir : Path
        The report directory; ``out_dir / "index.md"`` links every experiment's report.
    experiments : tuple[str, ...]
        Experiments a report was written for, sorted.
    files : tuple[Path, ...]
        Every file written.
    warnings : tuple[str, ...]
        One line per problem found (skipped file, missing method, partial run, ...).
    """

    out_dir: Path
    experiments: tuple[str, ...]
    files: tuple[Path, ...]
    warnings: tuple[str, ...]
    studies: tuple[str, ...] = ()  # studies reported (ilcforce.report.study), the paper's Monte Carlo first
    html: Any = None  # the HTML pages (ilcforce.report.html.HtmlReport), None when not written

    @property
    def index(self) -> Path:
        return self.out_dir / "index.md"


@dataclass
class _Method:
    """One readable store (internal)."""

    name: str
    path: Path
    provenance: dict[str, Any]
    metrics: pd.DataFrame


@dataclass
class _Experiment:
    """What was read for one experiment, plus its warnings (internal)."""

    name: str
    methods: dict[str, _Method] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    notes: dict[str, str] = field(default_factory=dict)  # figure stem -> why it was not drawn
    variant: str = ""  # why this is a user's variant, not an experiment file as written ("" when it is one)

    def warn(self, text: str) -> None:
        self.warnings.append(f"{self.name}: {' '.join(str(text).split())}")

    @property
    def metrics(self) -> dict[str, pd.DataFrame]:
        return {name: method.metrics for name, method in self.methods.items()}

    def config(self, method: str | None = None) -> dict:
        """The stored configuration of ``method`` (of the first method when None)."""
        chosen = self.methods.get(method) if method else next(iter(self.methods.values()), None)
        return sections.config_of(chosen.provenance) if chosen is not None else {}

    def label(self, method: str, flags: Mapping[str, str] | None = None) -> str:
        return sections.method_label(method, self.config(method), flags)


# ---------------------------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------------------------


def perturbation_iteration(provenance: Mapping[str, Any]) -> int:
    """``plant.perturbation.from_iteration`` from the stored JSON config; 10 if absent."""
    try:
        config = json.loads(str(provenance.get("config_json", "")))
        value = config["plant"]["perturbation"]["from_iteration"]
        return int(value)
    except (ValueError, KeyError, TypeError):
        return paper.PERTURBATION_ITERATION


def _load_experiment(name: str, paths: Mapping[str, Path]) -> _Experiment:
    experiment = _Experiment(name)
    reader_major, reader_minor = (int(x) for x in store.SCHEMA_VERSION.split("."))
    for method in tables.ordered_methods(paths):
        path = paths[method]
        try:
            store.validate(path)
            provenance = store.read_provenance(path)
            metrics = store.read_metrics(path)
        except _READ_ERRORS as error:
            experiment.warn(f"skipped {path.name}: {error}")
            continue
        stored_method = str(provenance.get("method", method))
        if stored_method != method:
            experiment.warn(f"{path.name} holds method {stored_method!r}; reported as {method!r} (its file name)")
        version = str(provenance.get("schema_version", ""))
        try:
            major, minor = (int(x) for x in version.split("."))
            if (major, minor) > (reader_major, reader_minor):
                experiment.warn(
                    f"{path.name}: written with newer schema {version} (this reader: {store.SCHEMA_VERSION}); "
                    "fields added since are ignored"
                )
        except ValueError:
            pass
        run_state = str(provenance.get("run_state", ""))
        requested = provenance.get("n_iterations_requested")
        if run_state in ("running", "partial"):
            why = "still running or killed" if run_state == "running" else "stopped before finishing"
            experiment.warn(
                f"{method}: partial results (run_state {run_state!r}, {why}): {len(metrics.index)} of "
                f"{requested} iterations stored"
            )
        if len(metrics.index) == 0:
            experiment.warn(f"{method}: store holds no complete iteration; skipped")
            continue
        experiment.methods[method] = _Method(method, path, provenance, metrics)
        why = sections.variant_reason(name, provenance)
        if why and not experiment.variant:
            experiment.variant = f"{method}: {why}"
    for method in EXPECTED_METHODS:
        if method not in experiment.methods and method not in paths:
            experiment.warn(f"method {method} missing (no {method}.h5); claims that need it are not evaluable")
        elif method not in experiment.methods:
            experiment.warn(f"method {method} missing (its store was skipped); claims that need it are not evaluable")
    for method, loaded in experiment.methods.items():
        j = tables.chattering_iteration(loaded.metrics)
        if j is not None and j != paper.CHATTERING_ITERATION:
            experiment.warn(
                f"{method}: no complete iteration {paper.CHATTERING_ITERATION} (the paper's; not run, or not "
                f"completed); Table 3 and Figs. 6, 7 use iteration {j}, the last complete one"
            )
    return experiment


# ---------------------------------------------------------------------------------------------
# Entry point
# ---------------------------------------------------------------------------------------------


def _write_experiment(
    experiment: _Experiment, directory: Path, formats: tuple[str, ...]
) -> tuple[list[Path], pd.DataFrame]:
    directory.mkdir(parents=True, exist_ok=True)
    p = paper.PERTURBATION_ITERATION
    found = {perturbation_iteration(m.provenance) for m in experiment.methods.values()}
    if found:
        p = min(found)
        if len(found) > 1:
            experiment.warn(f"methods disagree on the perturbation iteration {sorted(found)}; using {p}")
    metrics = experiment.metrics
    table2 = tables.table2(metrics)
    table3 = tables.table3(metrics)
    comparison = tables.comparison_frame(metrics)
    tidy = tidy_metrics(experiment)
    deterministic = claims_module.is_deterministic(experiment.config())
    claims = claims_module.judge_claims_over_seeds(tidy, perturbation_iteration=p, deterministic=deterministic,
                                                   config=experiment.config("c1") or experiment.config())
    growth = stability.learning_growth(tidy, perturbation_iteration=p, config=experiment.config())
    flags = stability.unstable_methods(growth)
    summary = claims_module.claim_summary(claims)
    claim_rows = verdict_rows.claim_rows(claims, source=verdict_rows.EXPERIMENT, name=experiment.name,
                                         setting=experiment.name)
    stability_rows = verdict_rows.stability_rows(growth, source=verdict_rows.EXPERIMENT, name=experiment.name,
                                                 setting=experiment.name)
    written: list[Path] = []
    written += table_write.write_table(table2, directory, "table2", title=f"Table 2 ({experiment.name})")
    written += table_write.write_table(table3, directory, "table3", title=f"Table 3 ({experiment.name})")
    written.append(table_write.write_csv(comparison, directory / "comparison.csv"))
    written.append(
        table_write.write_markdown(
            tables.by_quantity(comparison), directory / "comparison.md", title=f"Comparison ({experiment.name})"
        )
    )
    written.append(table_write.write_markdown(summary, directory / "claims.md", title=f"Claims ({experiment.name})"))
    written.append(table_write.write_csv(claim_rows, directory / "claims.csv"))  # the verdicts as data
    written.append(table_write.write_csv(stability_rows, directory / "stability.csv"))
    written.append(table_write.write_csv(claims, directory / "claim_parts.csv"))
    figure_files = _write_figures(experiment, directory, p, formats, flags)
    written += figure_files
    report = directory / "report.md"
    write_text_whole(report, _report_text(
        experiment,
        p=p,
        table2=table2,
        table3=table3,
        comparison=comparison,
        claims=claims,
        growth=growth,
        flags=flags,
        figure_files=figure_files,
    ))
    written.append(report)
    summary.attrs["description"] = sections.description(experiment.config())
    summary.attrs["variant"] = experiment.variant
    summary.attrs["diverged"] = {name: found[0] for name, method in experiment.methods.items()
                                 if (found := tables.divergence(method.metrics)) is not None}
    summary.attrs["flags"] = dict(flags)
    summary.attrs["claim_rows"] = claim_rows.to_dict("list")
    summary.attrs["stability_rows"] = stability_rows.to_dict("list")
    summary.attrs["divergence"] = _divergence_lines(experiment, {}, p)
    summary.attrs["task_loss"] = {m: lost for m, frame in metrics.items()
                                  if tables.divergence(frame) is None and (lost := tables.task_loss(frame, p))}
    summary.attrs["diverged"] = {m: found[0] for m, frame in metrics.items()
                                 if (found := tables.divergence(frame)) is not None}
    # the iterations the run asked for (a diverged method stops early)
    requested = [m.provenance.get("n_iterations_requested") for m in experiment.methods.values()]
    requested = [int(n) for n in requested if isinstance(n, (int, float, np.integer)) and n > 0]
    summary.attrs["iterations"] = max(requested) if requested else max(
        (len(frame.index) for frame in metrics.values()), default=0)
    return written, summary


def _misplaced_files(results_dir: Path) -> list[str]:
    """One warning per ``*.h5`` directly in ``results_dir``: stores live one level down.

    (Every ``*.h5`` one level down is listed by find_stores and validated with the experiment.)
    """
    warnings = []
    for path in sorted(results_dir.glob("*.h5")):
        if path.is_file():
            warnings.append(f"{path}: skipped, not in an experiment directory (expected <experiment>/<method>.h5)")
    return warnings


def _report_experiment(name: str, paths: Mapping[str, Path], out_dir: Path, formats: tuple[str, ...],
                       progress: Callable[[str], None] | None = None):
    """One experiment's report (a pool task). Returns (files, claims or None, warnings)."""
    experiment = _load_experiment(name, paths)
    if not experiment.methods:
        experiment.warn("no readable store; no report written")
        return [], None, experiment.warnings
    if progress is not None:
        progress(f"experiment {name}: {count_text(len(experiment.methods), 'store')} read and checked; tables, claims, "
                 "figures")
    files, claims = _write_experiment(experiment, out_dir / name, formats)
    return files, claims, experiment.warnings


def write_report(
    results_dir: Path, out_dir: Path, *, formats: tuple[str, ...] = DEFAULT_FORMATS, jobs: int = 1,
    progress: Callable[[str], None] | None = None,
) -> ReportSummary:
    """Write the report for every experiment under ``results_dir`` into ``out_dir``.

    Parameters
    ----------
    results_dir : Path
        Holds ``<experiment>/<method>.h5`` stores (see :func:`ilcforce.store.find_stores`).
    out_dir : Path
        Created if missing; ``out_dir/<experiment>/`` per experiment and ``out_dir/index.md``. With
        nothing usable under ``results_dir`` nothing is written there (an earlier report stays whole).
        The report is built beside it and replaces it whole at the end (:mod:`ilcforce.report.folder`):
        it must be absent, empty or a report ilcforce wrote, else ReportFolderError before anything
        is read; a report stopped midway leaves the previous one whole.
    formats : tuple of str
        Figure file formats (matplotlib names): PNG by default, which the pages link; add "pdf"
        (FIGURE_FORMATS) for vector figures.
    jobs : int
        Experiments reported in parallel worker processes (1: all in this process). Each
        experiment's files are the same either way.

    Returns
    -------
    ReportSummary
        Experiments reported, files written, and one warning line per problem. Never raises for
        a bad input file; raises :class:`ilcforce.store.StoreError` only if ``results_dir`` is
        not a directory, :class:`ilcforce.report.folder.ReportFolderError` if ``out_dir`` is not a
        folder the report may replace, and OSError (naming the file) if ``out_dir`` cannot be written.
    """
    results_dir = Path(results_dir)
    out_dir = Path(out_dir)
    target = report_folder.check_target(out_dir, results_dir)  # before anything is read or written
    found = store.find_stores(results_dir)
    found.pop("studies", None)  # results/studies/ holds study stores: reported by ilcforce.report.study below
    warnings: list[str] = _misplaced_files(results_dir)
    for name in [name for name in found if name.casefold() in RESERVED_NAMES]:  # a folder renamed by hand
        warnings.append(f"{results_dir / name}: skipped, its name is one the report writes itself; rename the folder")
        del found[name]
    from ilcforce.report.study_match import find_study_stores

    study_dir = results_dir / "studies"
    report_paths = find_study_stores(results_dir)
    findings_paths = sorted(study_dir.glob("*.h5")) if study_dir.is_dir() else []
    if not found and not report_paths and not findings_paths and not (results_dir / "tuning").is_dir():  # nothing to report: out_dir is left as it is
        return ReportSummary(out_dir=out_dir, experiments=(), files=(), warnings=tuple(warnings))
    with report_folder.building(target) as staging:
        try:
            summary = _write_into(results_dir, staging, found, report_paths, findings_paths, warnings,
                                  formats=formats, jobs=jobs, progress=progress)
        except OSError as error:  # named by the file it will have, not by the building folder's
            if error.filename and str(error.filename).startswith(str(staging)):
                raise type(error)(error.errno, error.strerror or str(error),
                                  _moved(Path(error.filename), staging, out_dir).as_posix()) from None
            raise
        if staging / "index.md" not in summary.files:  # every store unusable: the previous report stays
            return ReportSummary(out_dir=out_dir, experiments=(), files=(), warnings=summary.warnings)
        report_folder.publish(staging, target, __version__)
    page = summary.html
    return dataclasses.replace(
        summary, out_dir=out_dir, files=tuple(_moved(path, staging, out_dir) for path in summary.files),
        warnings=tuple(w.replace(str(staging), str(out_dir)) for w in summary.warnings),
        html=None if page is None else dataclasses.replace(
            page, path=_moved(page.path, staging, out_dir), site=tuple(_moved(p, staging, out_dir) for p in page.site)))


def _long_run_title(path: Path) -> str:
    """The title of one of make long's pages (its first line, a heading), "" for its tables' pages."""
    first = path.read_text(encoding="utf-8").split("\n", 1)[0]
    page = f"{long_run.REPORT_FOLDER}/{path.name}"
    return first.removeprefix("# ") if first.startswith("# ") and page in html.LONG_RUN_PAGES else ""


def _moved(path: Path, staging: Path, out_dir: Path) -> Path:
    """Where ``path``, written under ``staging``, is once the report is in place."""
    return out_dir / Path(path).relative_to(staging)


def _write_into(results_dir: Path, out_dir: Path, found: dict, report_paths: list, findings_paths: list,
                warnings: list[str], *, formats: tuple[str, ...], jobs: int,
                progress: Callable[[str], None] | None) -> ReportSummary:
    """The report of ``write_report`` written into the empty folder ``out_dir``."""
    written: list[Path] = []
    verdicts: dict[str, pd.DataFrame] = {}
    experiment_warnings: dict[str, list[str]] = {}
    # every experiment, every study's report and every study's findings page is one task; they run on
    # `jobs` cores together, heaviest first, and are put together below in this fixed order
    from ilcforce.report.study import study_index_section

    pieces = [pool.Task(f"experiment {name}", _report_experiment, (name, paths, out_dir, tuple(formats)),
                        cost=tasks.experiment_cost(paths.values())) for name, paths in found.items()]
    pieces += [pool.Task(f"study {path.stem}", tasks.study_report, (path, out_dir / "studies", tuple(formats)),
                         cost=tasks.study_cost(path, 2.0)) for path in report_paths]
    pieces += [pool.Task(f"findings of study {path.stem}", tasks.study_findings_page, (path, out_dir / "studies"),
                         cost=tasks.study_cost(path, 0.1)) for path in findings_paths]
    if progress is not None:
        progress(f"{len(found)} experiment(s), {len(report_paths)} study report(s), {len(findings_paths)} findings "
                 f"page(s) on {max(1, min(jobs, len(pieces)))} process(es)")
    outcomes = pool.run_tasks(pieces, jobs=jobs, progress=progress)
    n_experiments, n_reports = len(found), len(report_paths)
    for name, (files, claims, experiment_warns) in zip(found, outcomes[:n_experiments]):
        warnings += experiment_warns
        if claims is None:
            continue
        written += files
        verdicts[name] = claims
        experiment_warnings[name] = experiment_warns
    study_reports = outcomes[n_experiments:n_experiments + n_reports]
    study_section = study_index_section(study_reports)
    for study_report in study_reports:
        written += study_report.files
        warnings += study_report.warnings
    studies: dict[str, dict] = {}
    for outcome in outcomes[n_experiments + n_reports:]:
        if isinstance(outcome, str):
            warnings.append(outcome)
            continue
        files, name, found_study = outcome
        written += files
        studies[name] = found_study
    if studies:  # the findings pages (stability boundary, per-setting verdicts and flags) next to the reports
        study_section = [*study_section, "Findings per study (verdicts, unstable learning, first diverged "
                         "iteration per setting; the stability-boundary figure for one-key sweeps): "
                         + ", ".join(f"[{n}](studies/{n}/findings.md)" for n in sorted(studies)), ""]
    from ilcforce.report.tuning import tuning_pages  # matplotlib's axes only when the report runs

    sources = {facts["tuning_source"] for facts in studies.values() if facts.get("tuning_source")}
    tuning_lines = tuning_pages(results_dir, out_dir, tuple(formats), written, warnings, sources)
    if tuning_lines:  # `ilcforce tune`'s stores: per method the objective against the trial and the chosen gains
        study_section = [*study_section, "## Tuning", "", *tuning_lines, ""]
    # `make long`'s pages: from its studies where stored, else as committed (make reproduce does not run them)
    long_files = long_run.report_pages(results_dir, out_dir / long_run.REPORT_FOLDER)
    written += long_files
    long_pages = sorted(((path.name, title) for path in long_files if path.suffix == ".md"
                         and (title := _long_run_title(path))),
                        key=lambda page: html.LONG_RUN_PAGES.index(f"{long_run.REPORT_FOLDER}/{page[0]}"))
    if long_pages:
        study_section = [*study_section, "## Long runs", "",
                         *(f"* [{title}]({long_run.REPORT_FOLDER}/{name}) (`make long`)" for name, title in long_pages),
                         ""]
    reported = tuple(r.name for r in study_reports if r.index_lines)
    if not verdicts and not reported and not studies:  # every store was unusable: an existing report stays
        if tuning_lines:  # a results folder of tuning stores only: their pages, and an index linking them
            write_text_whole(out_dir / "index.md", "\n".join(["# ilcforce reports", "", *study_section]))
            written.append(out_dir / "index.md")
        return ReportSummary(out_dir=out_dir, experiments=(), files=tuple(written), warnings=tuple(warnings))
    index = out_dir / "index.md"
    title, rest = index_text(results_dir, verdicts, experiment_warnings, warnings).split("\n", 1)
    write_text_whole(index, "\n".join([title, "", *study_section]) + rest)  # studies lead
    written.append(index)
    # every verdict of every experiment and study as rows; the findings are written from these rows
    all_claims = pd.concat([pd.DataFrame(f.attrs.get("claim_rows", {}), columns=verdict_rows.CLAIM_COLUMNS)
                            for f in verdicts.values()]
                           + [pd.DataFrame(s.get("claim_rows", {}), columns=verdict_rows.CLAIM_COLUMNS)
                              for s in studies.values()], ignore_index=True)
    all_stability = pd.concat([pd.DataFrame(f.attrs.get("stability_rows", {}), columns=verdict_rows.STABILITY_COLUMNS)
                               for f in verdicts.values()]
                              + [pd.DataFrame(s.get("stability_rows", {}), columns=verdict_rows.STABILITY_COLUMNS)
                                 for s in studies.values()], ignore_index=True)
    for column in ("judged", "saturating", "inconclusive", "flagged"):  # concatenating an empty frame leaves them float
        all_stability[column] = all_stability[column].astype(bool)
    written.append(table_write.write_csv(all_claims, out_dir / "claims.csv"))
    written.append(table_write.write_csv(all_stability, out_dir / "stability.csv"))
    findings = out_dir / "findings.md"  # experiment files as written only: a user's variant is not the README's
    write_text_whole(findings, readme.findings_markdown(
        {name: {"description": frame.attrs.get("description", ""), "diverged": frame.attrs.get("diverged", {}),
                "iterations": frame.attrs.get("iterations", 0), "task_loss": frame.attrs.get("task_loss", {})}
         for name, frame in verdicts.items() if not frame.attrs.get("variant")}, studies,
        claims=verdict_rows.read_back(out_dir / "claims.csv"),
        stability=verdict_rows.read_back(out_dir / "stability.csv")))
    written.append(findings)
    page = html.write_html(out_dir)  # last: it is made of the Markdown pages written above
    if page is not None:
        written += page.site
    return ReportSummary(
        out_dir=out_dir,
        experiments=tuple(sorted(verdicts)),
        files=tuple(written),
        warnings=tuple(warnings),
        studies=reported,
        html=page,
    )
