"""Write the report: tables, claims, figures and a readable ``report.md`` per experiment.

Reads only the results store (:mod:`ilcforce.store`); never simulates. Layout written::

    <out_dir>/index.md                      links to every experiment's report
    <out_dir>/<experiment>/report.md        readable on its own
    <out_dir>/<experiment>/table2.csv|.md   Table 2, ours beside the paper's
    <out_dir>/<experiment>/table3.csv|.md   Table 3, ours beside the paper's
    <out_dir>/<experiment>/comparison.csv|.md
    <out_dir>/<experiment>/claims.csv|.md   the five claims with verdicts and rules
    <out_dir>/<experiment>/<figure>.png|.pdf

Problems with the inputs (an unreadable or foreign file, a missing method, a partial run, a newer
schema) never raise: each becomes one line in :attr:`ReportSummary.warnings` and in the report,
and everything that can still be reported is.
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor

import json
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

import ilcforce
from ilcforce import store
from ilcforce.report import claims as claims_module
from ilcforce.report import figures, paper, readme, sections, stability, study_findings, tables
from ilcforce.metrics import memory_norms

#: The methods an experiment is expected to hold.
EXPECTED_METHODS = tables.METHOD_ORDER

#: Figures written per experiment: file stem -> caption.
FIGURES = {
    "fig2_reference": "Fig. 2: desired position x_d and desired force F_yd",
    "fig3_position_error_norm": "Fig. 3: 2-norm of the position error (X) against iteration",
    "fig4_force_error_norm": "Fig. 4: 2-norm of the force error (Y) against iteration",
    "fig5_tracking_error": "Fig. 5: position error X and force error Y at j = 0, 5, 10, 15",
    "fig6_input_x": "Fig. 6: (a) control input and (b) Delta tau in X, C1 and C3 at j = 19",
    "fig7_input_y": "Fig. 7: (a) control input and (b) Delta tau in Y, C1 and C3 at j = 19",
    "fig_alpha_hat": "C3's learned switching gain alpha_hat_j(t) (not in the paper)",
    "fig_gravity": "Does C3 learn gravity? Theta_hat's G entries against the true J^-T G_q (plants with gravity)",
}
FIGURE_FORMATS = ("png", "pdf")

#: Errors a store reader may raise for a bad file (StoreError) or unexpected contents.
_READ_ERRORS = (store.StoreError, OSError, KeyError, ValueError, TypeError)


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
    for method in EXPECTED_METHODS:
        if method not in experiment.methods and method not in paths:
            experiment.warn(f"method {method} missing (no {method}.h5); claims that need it are not evaluable")
        elif method not in experiment.methods:
            experiment.warn(f"method {method} missing (its store was skipped); claims that need it are not evaluable")
    for method, loaded in experiment.methods.items():
        j = tables.chattering_iteration(loaded.metrics)
        if j is not None and j != paper.CHATTERING_ITERATION:
            experiment.warn(
                f"{method}: iteration {paper.CHATTERING_ITERATION} not complete; Table 3 and Figs. 6, 7 use "
                f"iteration {j}, the last complete one"
            )
    return experiment


# ---------------------------------------------------------------------------------------------
# Figures
# ---------------------------------------------------------------------------------------------


def _save(fig: Figure, directory: Path, stem: str, formats: tuple[str, ...]) -> list[Path]:
    written = []
    for fmt in formats:
        path = directory / f"{stem}.{fmt}"
        # No creation date in the PDF, so that an unchanged report is byte-identical.
        metadata = {"CreationDate": None} if fmt == "pdf" else None
        fig.savefig(path, format=fmt, metadata=metadata)
        written.append(path)
    return written


def _figure_builders(experiment: _Experiment, p: int,
                     flags: Mapping[str, str]) -> dict[str, Callable[[], Figure | str]]:
    """Stem -> a callable making the figure, or returning a one-line reason it cannot be drawn."""
    methods = experiment.methods
    labels = {m: figures.method_label(m) + "".join(
        f" [{d.split(',')[0]}]" for d in sections.law_differences(m, experiment.config(m)))
        + (f" ({stability.UNSTABLE})" if m in flags else "") for m in methods}

    def reference() -> Figure | str:
        first = next(iter(methods.values()))
        return figures.figure_reference(store.read_reference(first.path))

    def norms(column: str, ylabel: str) -> Callable[[], Figure | str]:
        return lambda: figures.figure_error_norm(experiment.metrics, column, ylabel, perturbation_iteration=p,
                                                 labels=labels)

    def tracking() -> Figure | str:
        frames: dict[str, dict[int, pd.DataFrame]] = {}
        for name, method in methods.items():
            stored = {int(j) for j in method.metrics.index}  # every committed iteration, diverged included
            frames[name] = {
                j: store.read_iteration(method.path, j) for j in figures.TRACKING_ITERATIONS if j in stored
            }
        return figures.figure_tracking_error(frames, labels=labels)

    def inputs(axis: str) -> Callable[[], Figure | str]:
        def build() -> Figure | str:
            chosen, read_at = {}, {}
            for name in ("c1", "c3"):
                if name not in methods:
                    continue
                j = tables.chattering_iteration(methods[name].metrics)
                if j is not None:
                    chosen[name] = store.read_iteration(methods[name].path, j)
                    read_at[name] = j
            if not chosen:
                return "no complete C1 or C3 iteration"
            return figures.figure_input(chosen, axis, iterations=read_at, labels=labels)

        return build

    def alpha_hat() -> Figure | str:
        if "c3" not in methods:
            return "no C3 results"
        method = methods["c3"]
        alphas = {}
        for j in tables.complete_iterations(method.metrics):
            memory = store.read_memory(method.path, j)
            if "alpha_hat" in memory:
                alphas[j] = memory["alpha_hat"]
        if not alphas:
            return "the C3 store holds no alpha_hat memory"
        duration = float(store.read_reference(method.path).index.to_numpy()[-1])
        profiles = figures.profile_iterations(list(alphas))
        unit = store.read_memory_units(method.path, max(alphas)).get("alpha_hat", "N")
        return figures.figure_switching_gain(alphas, duration, profiles=profiles, unit=unit)

    def gravity() -> Figure | str:
        if "c3" not in methods:
            return "no C3 results"
        from ilcforce.report.gravity import gravity_figure
        from ilcforce.store.run import open_run

        path = methods["c3"].path
        first = tables.complete_iterations(methods["c3"].metrics) or [int(j) for j in methods["c3"].metrics.index]
        if not first or store.read_memory(path, first[0])["theta_hat"].shape[1] != 12:
            return "the plant has no gravity: C3's Theta has no G entries"
        return gravity_figure(path, open_run(path).config)

    return {
        "fig2_reference": reference,
        "fig3_position_error_norm": norms("position_error_2norm", "position error 2-norm (m)"),
        "fig4_force_error_norm": norms("force_error_2norm", "force error 2-norm (N)"),
        "fig5_tracking_error": tracking,
        "fig6_input_x": inputs("x"),
        "fig7_input_y": inputs("y"),
        "fig_alpha_hat": alpha_hat,
        "fig_gravity": gravity,
    }


def _write_figures(experiment: _Experiment, directory: Path, p: int, formats: tuple[str, ...],
                   flags: Mapping[str, str]) -> list[Path]:
    written: list[Path] = []
    if not experiment.methods or not formats:
        for stem in FIGURES:
            experiment.notes[stem] = "no readable store" if not experiment.methods else "no figure format requested"
        return written
    for stem, build in _figure_builders(experiment, p, flags).items():
        try:
            with figures.report_style():
                made = build()
                if isinstance(made, str):
                    experiment.notes[stem] = made
                    continue
                written += _save(made, directory, stem, formats)
        except _READ_ERRORS as error:
            experiment.notes[stem] = f"not drawn: {' '.join(str(error).split())}"
            experiment.warn(f"{stem} not drawn: {error}")
    return written


# ---------------------------------------------------------------------------------------------
# report.md
# ---------------------------------------------------------------------------------------------

DEFINITIONS = """\
* Iterations are counted from j = 0. The paper's "iteration j = 20" (Table 3, Figs. 6, 7) is the
  20th iteration, our j = 19.
* Error 2-norm (Table 2, Figs. 3, 4): the paper's ||e||_2 = sqrt(sum_k e(t_k)^2) over the samples
  of the log grid (2001 samples at 1 ms for the paper's setup), for e_P (X, m) and e_F (Y, N).
  It grows with the number of samples; it is the definition whose magnitudes match Table 2.
  The stores also hold the grid-independent L2 norm sqrt(dt sum_k e(t_k)^2), the RMS and the max.
* Convergence iteration j̄ (Table 2; the paper never defines it): the first j <= 9 whose error
  2-norm is within 1.5x the median of iterations 5..9. Its 2-norm is the one at j̄.
* Chattering H (Table 3): the population standard deviation (ddof = 0) over the log grid of
  Delta = tau_d - tau, where tau_d is the inverse dynamics of that iteration's true plant along
  the desired motion with the desired contact force. Task space (X, Y: J^-T tau, N; the space
  whose magnitudes match the paper) and joint space (1, 2: N m). Read at j = 19.
* A diverged iteration (the watchdog stopped it) has no error norm and no H; the method's later
  iterations were not run.
"""


def _provenance_table(experiment: _Experiment) -> pd.DataFrame:
    rows = []
    for name, method in experiment.methods.items():
        prov = method.provenance
        rows.append(
            {
                "method": name,
                "file": method.path.name,
                "run_state": prov.get("run_state", ""),
                "iterations": f"{len(method.metrics.index)} of {prov.get('n_iterations_requested', '?')}",
                "seed": prov.get("seed", ""),
                "ilcforce": prov.get("ilcforce_version", ""),
                "git_commit": (str(prov.get("git_commit", "")) or "unknown")[:12],
                "created_utc": prov.get("created_utc", ""),
                "updated_utc": prov.get("updated_utc", ""),
                "schema": prov.get("schema_version", ""),
            }
        )
    return pd.DataFrame(rows)


def _config_section(experiment: _Experiment) -> list[str]:
    lines: list[str] = []
    groups: dict[str, list[str]] = {}
    for name, method in experiment.methods.items():
        groups.setdefault(str(method.provenance.get("config_toml", "")), []).append(name)
    for text, names in groups.items():
        lines.append(f"Configuration of {', '.join(names)} (TOML, as stored):")
        lines.append("")
        lines.append("```toml")
        lines.append(text.rstrip("\n") or "# (empty)")
        lines.append("```")
        lines.append("")
    lines.append("Command lines:")
    lines.append("")
    for name, method in experiment.methods.items():
        lines.append(f"* {name}: `{method.provenance.get('command', '')}`")
    lines.append("")
    return lines


def _divergence_lines(experiment: _Experiment, flags: Mapping[str, str]) -> list[str]:
    lines = []
    for name, method in experiment.methods.items():
        found = tables.divergence(method.metrics)
        if found is None:
            extra = f", but {flags[name]}" if name in flags else ""
            lines.append(f"* {name}: no divergence ({len(method.metrics.index)} iterations){extra}")
            continue
        j, time = found
        try:
            reason = store.read_iteration(method.path, j).attrs.get("diverged_reason", "") or "no reason stored"
        except _READ_ERRORS as error:
            reason = f"reason unreadable: {' '.join(str(error).split())}"
        extra = f"; before that, {flags[name]}" if name in flags else ""
        lines.append(f"* {name}: diverged at iteration {j}, t = {time:.4g} s: {reason}{extra}")
    return lines


def _fallback_table(experiment: _Experiment) -> pd.DataFrame:
    rows = []
    for name, method in experiment.methods.items():
        counts = method.metrics["fallback_count"].to_numpy(dtype=float)
        rows.append(
            {
                "method": name,
                "total": int(np.nansum(counts)),
                "max_per_iteration": int(np.nanmax(counts)) if counts.size else 0,
                "iterations_with_fallbacks": int(np.sum(counts > 0)),
            }
        )
    return pd.DataFrame(rows)


def tidy_metrics(experiment: _Experiment) -> pd.DataFrame:
    """The run's tidy frame (seed, method, iteration, metrics) with each learned memory's norm."""
    frame = claims_module.tidy_from_methods(experiment.metrics)
    norms: dict[tuple[str, int], dict[str, float]] = {}
    for name, method in experiment.methods.items():
        for j in tables.complete_iterations(method.metrics):
            try:
                norms[(name, j)] = memory_norms(store.read_memory(method.path, j))
            except _READ_ERRORS as error:
                experiment.warn(f"{name}: memory of iteration {j} unreadable ({error}); its norm is missing")
    columns = sorted({c for row in norms.values() for c in row})
    for column in columns:
        frame[column] = [norms.get((m, int(j)), {}).get(column, np.nan)
                         for m, j in zip(frame["method"], frame["iteration"], strict=True)]
    return frame


def _report_text(
    experiment: _Experiment,
    *,
    p: int,
    table2: pd.DataFrame,
    table3: pd.DataFrame,
    comparison: pd.DataFrame,
    claims: pd.DataFrame,
    growth: pd.DataFrame,
    flags: Mapping[str, str],
    figure_files: list[Path],
) -> str:
    md = tables.markdown_table
    lines = [f"# ilcforce report: experiment `{experiment.name}`", ""]
    own = sections.description(experiment.config())
    if own:
        lines += [f"**{own}**", ""]
    lines += [
        "Methods: " + "; ".join(experiment.label(m, flags) for m in experiment.methods) + ". "
        "C1 = sliding mode control (eq. 26), C2 = traditional ILC (eq. 27), C3 = the paper's ILC + "
        "sliding mode (eq. 14). "
        f"The m3 perturbation (x 1.4) acts from iteration j = {p} on (from the configuration). "
        f"Written by ilcforce {ilcforce.__version__} from the stores alone.",
        "",
        "## Warnings",
        "",
    ]
    lines += [f"* {w}" for w in experiment.warnings] or ["None."]
    lines += ["", "## Provenance", ""]
    if experiment.methods:
        lines.append(md(_provenance_table(experiment)))
        lines += _config_section(experiment)
    else:
        lines += ["No readable store for this experiment.", ""]
    lines += ["## Definitions", "", DEFINITIONS]
    lines += [
        "## Table 2: convergence iteration and error 2-norm at j̄",
        "",
        "Ours beside the paper's (`_paper` columns; the paper gives no C1 values).",
        "",
        md(table2),
        "## Table 3: chattering H at the 20th iteration",
        "",
        "`iteration` is the iteration read (19 unless that iteration was not run). The paper gives "
        "task-space values for C1 and C3 only. H is given in three forms: over the whole grid (SPEC "
        "section 6, the columns without suffix), without the t = 0 sample (`_no_t0`) and settled, from "
        "t >= 20 ms (`_settled`). Every iteration starts at rest while the reference asks for "
        "dF_yd/dt(0) = 5 pi + 5 N/s, so Delta at t = 0 is a mismatch no learning removes; the settled "
        "form is the one that leaves the start transient out.",
        "",
        md(table3),
        "## Comparison of the methods",
        "",
        "Error 2-norms at j = 0, j̄, 9, 10 (first perturbed iteration in the paper's setup) and 19; "
        "H at the 20th iteration; divergence; implicit-loop fallbacks over all iterations.",
        "",
        md(tables.by_quantity(comparison)),
        "## The paper's claims",
        "",
        "Verdicts come from our numbers only; the paper's figures are shown for comparison. "
        f"p = {p} is the perturbation iteration (from the configuration).",
        "",
    ]
    lines += sections.claims_markdown(claims, flags)
    lines += ["## Learning stability", ""]
    lines += sections.stability_markdown(growth, flags)
    lines += ["## Divergence", ""]
    lines += _divergence_lines(experiment, flags) or ["No readable store."]
    lines += ["", "## Implicit-loop fallbacks", ""]
    lines += [
        "Control samples where the implicit acceleration scheme found no real solution and reused the "
        "previous sample's acceleration (SPEC section 4), per method.",
        "",
    ]
    lines.append(md(_fallback_table(experiment)) if experiment.methods else "No readable store.\n")
    lines += ["## Figures", ""]
    for stem, caption in FIGURES.items():
        made = sorted((p.name for p in figure_files if p.stem == stem), key=lambda n: not n.endswith(".png"))
        if made:
            others = " ".join(f"([{name.rsplit('.', 1)[-1].upper()}]({name}))" for name in made[1:])
            lines += [f"### {caption}", "", f"![{caption}]({made[0]}) {others}".rstrip(), ""]
        else:
            lines += [f"### {caption}", "", f"Not drawn: {experiment.notes.get(stem, 'unknown reason')}.", ""]
    lines += [
        "## Files",
        "",
        "Tables as CSV (full precision) and Markdown: [table2](table2.md), [table3](table3.md), "
        "[comparison](comparison.md), [claims](claims.md).",
        "",
    ]
    return "\n".join(lines)


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
    claims = claims_module.judge_claims_over_seeds(tidy, perturbation_iteration=p)
    growth = stability.learning_growth(tidy, perturbation_iteration=p)
    flags = stability.unstable_methods(growth)
    summary = claims_module.claim_summary(claims)
    written: list[Path] = []
    written += tables.write_table(table2, directory, "table2", title=f"Table 2 ({experiment.name})")
    written += tables.write_table(table3, directory, "table3", title=f"Table 3 ({experiment.name})")
    written.append(tables.write_csv(comparison, directory / "comparison.csv"))
    written.append(
        tables.write_markdown(
            tables.by_quantity(comparison), directory / "comparison.md", title=f"Comparison ({experiment.name})"
        )
    )
    written += tables.write_table(summary, directory, "claims", title=f"Claims ({experiment.name})")
    written.append(tables.write_csv(claims, directory / "claim_parts.csv"))
    written.append(tables.write_csv(growth, directory / "learning_growth.csv"))
    figure_files = _write_figures(experiment, directory, p, formats, flags)
    written += figure_files
    report = directory / "report.md"
    report.write_text(
        _report_text(
            experiment,
            p=p,
            table2=table2,
            table3=table3,
            comparison=comparison,
            claims=claims,
            growth=growth,
            flags=flags,
            figure_files=figure_files,
        ),
        encoding="utf-8",
    )
    written.append(report)
    summary.attrs["description"] = sections.description(experiment.config())
    summary.attrs["flags"] = dict(flags)
    summary.attrs["parts"] = claims.to_dict("list")
    summary.attrs["divergence"] = _divergence_lines(experiment, {})
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


def _report_experiment(name: str, paths: Mapping[str, Path], out_dir: Path, formats: tuple[str, ...]):
    """One experiment's report (a process-pool task). Returns (files, claims or None, warnings)."""
    experiment = _load_experiment(name, paths)
    if not experiment.methods:
        experiment.warn("no readable store; no report written")
        return [], None, experiment.warnings
    files, claims = _write_experiment(experiment, out_dir / name, formats)
    return files, claims, experiment.warnings


def write_report(
    results_dir: Path, out_dir: Path, *, formats: tuple[str, ...] = FIGURE_FORMATS, jobs: int = 1,
    progress: Callable[[str], None] | None = None,
) -> ReportSummary:
    """Write the report for every experiment under ``results_dir`` into ``out_dir``.

    Parameters
    ----------
    results_dir : Path
        Holds ``<experiment>/<method>.h5`` stores (see :func:`ilcforce.store.find_stores`).
    out_dir : Path
        Created if missing; ``out_dir/<experiment>/`` per experiment and ``out_dir/index.md``.
    formats : tuple of str
        Figure file formats (matplotlib names), PNG and PDF by default. The report links the PNG.
    jobs : int
        Experiments reported in parallel worker processes (1: all in this process). Each
        experiment's files are the same either way.

    Returns
    -------
    ReportSummary
        Experiments reported, files written, and one warning line per problem. Never raises for
        a bad input file; raises :class:`ilcforce.store.StoreError` only if ``results_dir`` is
        not a directory, and OSError if ``out_dir`` cannot be written.
    """
    results_dir = Path(results_dir)
    out_dir = Path(out_dir)
    found = store.find_stores(results_dir)
    found.pop("studies", None)  # results/studies/ holds study stores: reported by ilcforce.report.study below
    warnings: list[str] = _misplaced_files(results_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    verdicts: dict[str, pd.DataFrame] = {}
    experiment_warnings: dict[str, list[str]] = {}
    tasks = [(name, paths, out_dir, tuple(formats)) for name, paths in found.items()]
    if jobs > 1 and len(tasks) > 1:
        context = multiprocessing.get_context("fork")  # workers inherit the imported modules
        with ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=context) as pool:
            outcomes = []
            for task, outcome in zip(tasks, pool.map(_report_experiment, *zip(*tasks))):
                outcomes.append(outcome)
                if progress is not None:
                    progress(f"experiment {task[0]} ({len(outcomes)} of {len(tasks)})")
    else:
        outcomes = []
        for task in tasks:
            outcomes.append(_report_experiment(*task))
            if progress is not None:
                progress(f"experiment {task[0]} ({len(outcomes)} of {len(tasks)})")
    for (name, *_rest), (files, claims, experiment_warns) in zip(tasks, outcomes):
        warnings += experiment_warns
        if claims is None:
            continue
        written += files
        verdicts[name] = claims
        experiment_warnings[name] = experiment_warns
    from ilcforce.report.study import write_study_reports

    study_reports, study_section = write_study_reports(results_dir, out_dir, formats=tuple(formats),
                                                       progress=progress)
    for study_report in study_reports:
        written += study_report.files
        warnings += study_report.warnings
    studies: dict[str, dict] = {}
    for path in sorted((results_dir / "studies").glob("*.h5")) if (results_dir / "studies").is_dir() else []:
        try:
            files, name, found_study = study_findings.write_study_findings(path, out_dir / "studies")
        except Exception as error:  # one bad study store never aborts the report  # noqa: BLE001
            warnings.append(f"{path}: study findings not written: {' '.join(str(error).split())}")
            continue
        written += files
        studies[name] = found_study
    if studies:  # the findings pages (stability boundary, per-setting verdicts and flags) next to the reports
        study_section = [*study_section, "Findings per study (verdicts, unstable learning, first diverged "
                         "iteration per setting; the stability-boundary figure for one-key sweeps): "
                         + ", ".join(f"[{n}](studies/{n}/findings.md)" for n in sorted(studies)), ""]
    index = out_dir / "index.md"
    title, rest = _index_text(results_dir, verdicts, experiment_warnings, warnings).split("\n", 1)
    index.write_text("\n".join([title, "", *study_section]) + rest, encoding="utf-8")  # studies lead
    written.append(index)
    findings = out_dir / "findings.md"
    findings.write_text(readme.findings_markdown({
        name: {"description": frame.attrs.get("description", ""), "parts": pd.DataFrame(frame.attrs.get("parts", {})),
               "flags": frame.attrs.get("flags", {}), "divergence": frame.attrs.get("divergence", [])}
        for name, frame in verdicts.items()}, studies), encoding="utf-8")
    written.append(findings)
    return ReportSummary(
        out_dir=out_dir,
        experiments=tuple(sorted(verdicts)),
        files=tuple(written),
        warnings=tuple(warnings),
        studies=tuple(r.name for r in study_reports if r.index_lines),
    )


def _index_text(
    results_dir: Path,
    verdicts: Mapping[str, pd.DataFrame],
    experiment_warnings: Mapping[str, list[str]],
    warnings: list[str],
) -> str:
    lines = ["# ilcforce reports", "",
             "One report per experiment: each runs C1 (sliding mode), C2 (traditional ILC) and C3 (the paper's "
             "ILC + sliding mode law) under the setting its description names, and judges the paper's five "
             "claims part by part.", "", f"Results read from `{results_dir}`.", ""]
    if not verdicts:
        lines += ["No experiment found (expected `<experiment>/<method>.h5` stores).", ""]
    else:
        rows = []
        for name, claims in verdicts.items():
            row: dict[str, object] = {"experiment": f"[{name}]({name}/report.md)",
                                      "description": claims.attrs.get("description", "")}
            for claim in claims.itertuples(index=False):
                row[f"claim {claim.claim}"] = claim.verdict
            flagged = claims.attrs.get("flags", {})
            row["unstable learning"] = ", ".join(flagged) if flagged else "none"
            row["warnings"] = len(experiment_warnings.get(name, []))
            rows.append(row)
        lines += ["Verdicts on the paper's five claims (see each report for the numbers and rules):", ""]
        lines.append(tables.markdown_table(pd.DataFrame(rows)))
        for number, claim in enumerate(claims_module.CLAIMS, start=1):
            lines.append(f"{number}. {claim.statement}")
        lines.append("")
    lines += ["## Warnings", ""]
    lines += [f"* {w}" for w in warnings] or ["None."]
    lines.append("")
    return "\n".join(lines)

