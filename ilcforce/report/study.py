"""The report of a study (``results/studies/<name>.h5``): every number over seeds, with its interval.

Per setting and method, each key number is the **median over seeds with a 95% percentile-bootstrap
interval of the median** (:func:`ilcforce.stats.median_interval`). Why this interval: per-seed
error norms and ratios are skewed and j̄ is discrete, so a normal-theory (mean +- t s) interval
would be wrong; the percentile bootstrap assumes no shape, and its resampling RNG is seeded, so
a report is reproducible. Seeds where a number does not exist (a divergence, a missing iteration)
are dropped and the count ``n`` is shown. Claims are judged seed by seed and summarised as
frequencies (:func:`ilcforce.report.claims.judge_claims_over_seeds`).

Written to ``<report>/studies/<name>/``: ``report.md``, ``key_numbers_s<k>.csv`` per setting,
``claims_s<k>.csv``, the figures (:mod:`ilcforce.report.study_figures`; Figs. 5-7 over seeds:
:mod:`ilcforce.report.seed_bands`).
"""

from __future__ import annotations

import json
from datetime import datetime, timezone
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from ilcforce.metrics import convergence_iteration
from ilcforce.records import TASK_DIMENSIONS, task_axes
from ilcforce.report import claim_parts, paper, table_write, tables
from ilcforce.report.figure_files import write_text_whole
from ilcforce.report.seedframes import SeedMetrics, split_seeds
from ilcforce.report.study_match import study_methods_and_seeds
from ilcforce.stats import Interval, format_interval, median_interval

#: Iterations whose error norms are tabulated (clipped to the study's iterations).
KEY_ITERATIONS = (0, 9, 10, 19)
#: Windows (inclusive) over which error norms are averaged per seed.
WINDOWS = ((5, 9), (15, 19))
NORMS = (("position", "position_error_2norm", "m"), ("force", "force_error_2norm", "N"))

INTERVAL_TEXT = (
    "Every number is the median over seeds with its 95% percentile-bootstrap interval of the median "
    "(2000 resamples, fixed RNG seed; `ilcforce.stats.median_interval`) and the number of seeds `n` it "
    "rests on. Why this interval: per-seed error norms and ratios are skewed and j̄ is discrete, so a "
    "normal-theory interval would be wrong; the bootstrap needs no shape assumption and is reproducible. "
    "Seeds where a number does not exist (a divergence before it, a missing iteration) are left out and "
    "counted in `n`.")


@dataclass
class StudyReport:
    """What :func:`write_study_report` wrote, and the lines the index shows for it."""

    name: str
    files: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    index_lines: list = field(default_factory=list)


def _per_seed(frame: pd.DataFrame, methods: list[str]) -> dict[str, dict[int, SeedMetrics]]:
    """method -> seed (ascending) -> that cell's metrics as arrays (:mod:`ilcforce.report.seedframes`)."""
    by_seed = split_seeds(frame)
    return {m: {seed: cells[m] for seed, cells in by_seed.items() if m in cells} for m in methods}


def _value(metrics: SeedMetrics, column: str, j: int) -> float:
    return metrics.value_at(column, j)  # NaN when the column or a complete iteration j is missing


def _window_mean(metrics: SeedMetrics, column: str, first: int, last: int) -> float:
    values = [_value(metrics, column, j) for j in range(first, last + 1)]
    return float(np.mean(values)) if values and all(math.isfinite(v) for v in values) else math.nan


def _diverged_at(metrics: SeedMetrics) -> float:
    found = metrics.divergence
    return float(found[0]) if found is not None else math.nan


#: The H columns the key numbers show when a frame has them: whole grid then settled, for the task
#: axes x, y of a 2-axis task and u, v, n of a 3-axis one (:func:`ilcforce.records.task_axes`).
H_COLUMNS = tuple(f"chattering_task_{axis}{form}" for n in TASK_DIMENSIONS for form in ("", "_settled")
                  for axis in task_axes(n))


def per_seed_numbers(frame: pd.DataFrame, methods: list[str], iterations: int) -> dict[str, dict[str, list[float]]]:
    """quantity -> method -> per-seed values (NaN where the number does not exist) for ONE setting."""
    last = iterations - 1
    key_js = sorted({min(j, last) for j in KEY_ITERATIONS} | {last})  # a long run's last iteration too
    out: dict[str, dict[str, list[float]]] = {}

    def put(quantity: str, method: str, value: float) -> None:
        out.setdefault(quantity, {}).setdefault(method, []).append(value)

    seeds = _per_seed(frame, methods)
    for method in methods:
        for seed, metrics in seeds[method].items():
            for quantity, column, unit in NORMS:
                for j in key_js:
                    put(f"{quantity} 2-norm at j = {j} ({unit})", method, _value(metrics, column, j))
                for first, end in WINDOWS:
                    if end <= last:
                        put(f"{quantity} 2-norm, mean j = {first}..{end} ({unit})", method,
                            _window_mean(metrics, column, first, end))
                if last >= 9:
                    norms = [_value(metrics, column, j) for j in range(last + 1)]
                    jb = convergence_iteration(norms)
                    put(f"j̄ {quantity}", method, math.nan if jb is None else float(jb))
            for j_h in sorted({min(paper.CHATTERING_ITERATION, last), last}):  # settled H beside the norms
                for column in H_COLUMNS:
                    if column in metrics.columns:
                        put(f"H {column.removeprefix('chattering_task_').replace('_', ' ')} at j = {j_h} (N)", method,
                            _value(metrics, column, j_h))
            put("first diverged iteration (diverged seeds only)", method, _diverged_at(metrics))
    # ratios, seed by seed (common random numbers: the methods of a seed saw the same draws)
    pairs = []
    if "c2" in methods and "c3" in methods and last >= 9:
        for quantity, column, _unit in NORMS:
            pairs.append((f"C3/C2 {quantity} 2-norm, mean j = 5..9", "c3", "c2",
                          lambda m, c=column: _window_mean(m, c, 5, 9)))
    if "c1" in methods and "c3" in methods:
        j_h = min(paper.CHATTERING_ITERATION, last)
        # the task axes the frame has H of: x, y (2 axes), else u, v, n (3 axes)
        axes = next((task_axes(n) for n in TASK_DIMENSIONS if f"chattering_task_{task_axes(n)[0]}" in frame.columns),
                    task_axes(2))
        # named as claims.csv names them: the whole-grid ratio at j = 19 on a judged axis is the number claim
        # 5 is judged on (claim_parts.CLAIM5_JUDGED); the settled one, and v (no paper counterpart), are shown
        judged_axes = {ours for n in claim_parts.CLAIM5_AXES for ours, _theirs, _r in claim_parts.CLAIM5_AXES[n]}
        for axis in axes:
            judged = j_h == paper.CHATTERING_ITERATION and axis in judged_axes
            tag = claim_parts.JUDGED_TAG if judged else claim_parts.SHOWN_TAG
            pairs.append((f"{claim_parts.h_ratio_name(j_h)}, {axis} {tag}", "c1", "c3",
                          lambda m, a=axis: _value(m, f"chattering_task_{a}", j_h)))
            pairs.append((f"{claim_parts.h_ratio_name(j_h, '_settled')}, {axis} {claim_parts.SHOWN_TAG}", "c1", "c3",
                          lambda m, a=axis: _value(m, f"chattering_task_{a}_settled", j_h)))
    for quantity, top, bottom, get in pairs:
        for seed in sorted(set(seeds[top]) & set(seeds[bottom])):
            numerator, denominator = get(seeds[top][seed]), get(seeds[bottom][seed])
            ratio = numerator / denominator if denominator and math.isfinite(denominator) else math.nan
            put(quantity, "ratio", ratio)
    return out


def key_numbers(frame: pd.DataFrame, methods: list[str], iterations: int,
                withheld: tuple[str, ...] = ()) -> pd.DataFrame:
    """One row per quantity, one column per method (and ``ratio``): "median [low, high] (n = k)"; a
    method the setting's tuned experiment withholds (no stable gains under its cap) has a column saying so."""
    from ilcforce.tune.heldout import NONE_UNDER_CAP

    numbers = per_seed_numbers(frame, methods, iterations)
    n_seeds = frame["seed"].nunique()
    rows = []
    for quantity, by_method in numbers.items():
        row = {"quantity": quantity}
        for method, values in by_method.items():
            values = np.asarray(values, dtype=float)
            if quantity.startswith("first diverged"):
                k = int(np.isfinite(values).sum())
                row[method] = (f"{k} of {count_text(n_seeds, 'seed')} diverged"
                               + (f"; {format_interval(median_interval(values))}" if k else ""))
                continue
            row[method] = _cell(median_interval(values), n_seeds)
        rows.append(row)
    for row in rows:
        row.update({m: NONE_UNDER_CAP for m in withheld})
    withheld = [m for m in withheld if m not in methods]
    columns = ["quantity", *tables.ordered_methods([*methods, *withheld]),
               *(["ratio"] if any("ratio" in r for r in rows) else [])]
    return pd.DataFrame(rows).reindex(columns=columns).fillna("-")


def _cell(interval: Interval, n_seeds: int) -> str:
    if interval.n == 0:
        return "-"
    text = format_interval(interval)
    return text if interval.n == n_seeds else f"{text} (n = {interval.n})"


def _config(config_json: str) -> dict:
    try:
        loaded = json.loads(config_json)
    except (ValueError, TypeError):
        return {}
    return loaded if isinstance(loaded, dict) else {}


def setting_perturbation(config_json: str) -> int:
    """A setting's perturbation iteration p, from its resolved configuration (the paper's 10 if absent)."""
    try:
        return int(json.loads(config_json)["plant"]["perturbation"]["from_iteration"])
    except (ValueError, KeyError, TypeError):
        return paper.PERTURBATION_ITERATION


def setting_iterations(config_json: str) -> int:
    """A setting's number of iterations, from its resolved configuration (the paper's 20 if absent)."""
    try:
        return int(json.loads(config_json)["experiment"]["iterations"])
    except (ValueError, KeyError, TypeError):
        return 20


def write_study_report(path: Path, out_dir: Path, *, formats: tuple[str, ...] = ("png",),
                       progress: Callable[[str], None] | None = None) -> StudyReport:
    """Write the report of the study store ``path`` into ``out_dir/<name>/``. Never raises for a bad store."""
    from ilcforce.report import claims as claims_module
    from ilcforce import stability
    from ilcforce.report import seed_bands, sections, study_figures
    from ilcforce.study import StudyStoreError, read_study

    report = StudyReport(Path(path).stem)
    try:
        results = read_study(path)
    except (StudyStoreError, OSError, KeyError, ValueError, TypeError) as exc:
        report.warnings.append(f"study {Path(path).name}: skipped ({' '.join(str(exc).split())})")
        return report
    name = Path(path).stem  # the file's own name: a renamed copy of a store is a page of its own
    report.name = name
    directory = Path(out_dir) / name
    directory.mkdir(parents=True, exist_ok=True)
    frame = results.metrics
    cells = results.cells
    done = int((cells["state"] == "done").sum()) if len(cells) else 0
    failed = cells[cells["state"] == "failed"] if len(cells) else cells
    seeds = sorted(frame["seed"].unique().tolist()) if len(frame) else []
    methods = tables.ordered_methods(frame["method"].unique().tolist()) if len(frame) else []
    lines = [f"# Study `{name}`", ""]
    if results.description:
        lines += [table_write.inert_markdown(results.description), ""]
    lines += [f"{done} cells done, {len(failed)} failed; {count_text(len(seeds), 'seed')} "
              f"({_seed_text(seeds)}), methods {', '.join(methods) or '-'}, {len(results.settings)} setting(s)"
              + _settings_text(results) + ".", ""]
    incomplete = incomplete_text(results)
    if incomplete:
        report.warnings.append(f"study {name}: incomplete (its latest run stopped early); see its report")
        lines += [incomplete, ""]
    lines += ["## How to read the numbers", "", INTERVAL_TEXT, ""]
    if len(failed):
        report.warnings.append(f"study {name}: {len(failed)} cell(s) failed; see its report")
        lines += ["## Failed cells", "", table_write.markdown_table(failed[["setting", "seed", "method", "attempts",
                                                                              "message"]]), ""]
    if not len(frame):
        report.warnings.append(f"study {name}: no finished cell to report")
    headline = []
    for setting in results.settings.itertuples(index=False):
        k = int(setting.setting)
        mine = results.setting_metrics(k) if len(frame) else frame
        if not len(mine):
            continue
        if progress is not None:
            progress(f"study {name}: setting {k + 1} of {len(results.settings)}")
        p = setting_perturbation(setting.config_json)
        iterations = setting_iterations(setting.config_json)
        title = setting.label if results.sweep_keys else "the study's setting"
        lines += [f"## Setting {k}: {title}" if results.sweep_keys else "## Results", ""]
        numbers = key_numbers(mine, methods, iterations, tuple(_config(setting.config_json).get("tuning", {})
                                                               .get("withheld", ())))
        report.files += table_write.write_table(numbers, directory, f"key_numbers_s{k}")
        lines += ["### Key numbers (median over seeds [95% bootstrap interval of the median])", "", table_write.markdown_table(numbers), ""]
        deterministic = claims_module.is_deterministic(_config(setting.config_json))
        judged = claims_module.first_seed_only(mine) if deterministic else mine  # one evaluation
        growth = stability.learning_growth(judged, perturbation_iteration=p, config=_config(setting.config_json))
        flags = stability.unstable_methods(growth)
        parts = claims_module.judge_claims_over_seeds(judged, perturbation_iteration=p, deterministic=deterministic,
                                                      config=_config(setting.config_json))
        report.files += table_write.write_table(parts, directory, f"claims_s{k}")
        lines += ["### The paper's claims over seeds", ""] + sections.claims_markdown(parts, flags)
        lines += ["### Learning stability", ""] + sections.stability_markdown(growth, flags)
        figures = study_figures.norm_band_figures(
            mine, directory, f"s{k}", formats, flags, perturbation_iteration=p,
            perturbation_label=sections.perturbation_label(sections.config_of({"config_json": setting.config_json})))
        report.files += figures
        lines += ["### Figs. 3 and 4 over seeds", "", study_figures.BAND_CAPTION, ""]
        lines += [f"![{f.stem}]({f.name})" for f in figures if f.suffix == ".png"] + [""]
        band_files, band_lines = seed_bands.seed_band_figures(
            mine, directory, f"s{k}", formats, flags, perturbation_iteration=p,
            perturbation_label=sections.perturbation_label(sections.config_of({"config_json": setting.config_json})))
        report.files += band_files
        lines += ["### Figs. 5-7 over seeds", ""] + band_lines
        if k == 0:
            headline = claims_module.claim_summary(parts)
    if results.sweep_keys and len(frame):
        if progress is not None:
            progress(f"study {name}: sweep figures")
        sweep_files, sweep_lines = study_figures.sweep_figures(results, directory, formats)
        report.files += sweep_files
        lines += ["## Over the sweep", ""] + sweep_lines
    lines += ["## The study file", "", "```toml", results.latest_study_toml.rstrip(), "```", "",
              "## Provenance", ""]
    for session in results.sessions:
        versions = ", ".join(f"{k} {v}" for k, v in session.get("versions", {}).items() if v)
        lines.append(f"* {session.get('started', '?')}: `{session.get('command', '')}` on "
                     f"{session.get('scheduler', '?')} ({session.get('workers', '?')} workers), {versions}")
    lines.append("")
    text_path = directory / "report.md"
    write_text_whole(text_path, "\n".join(lines))
    report.files.append(text_path)
    report.index_lines = _index_lines(name, results, headline, len(seeds), done, len(failed))
    return report


def incomplete_text(results) -> str:
    """A sentence for a study whose latest run stopped before storing every cell it planned
    (settings x seeds x methods of its study file); '' for a complete study or an older store."""
    planned, cells = results.planned_cells, results.cells
    if planned is None:
        return ""
    methods, seeds = study_methods_and_seeds(results.latest_study_toml)
    mine = cells
    if len(cells) and seeds:  # count only the cells of the latest plan (an earlier run may have had more)
        mine = cells[cells["seed"].isin(seeds)]
        mine = mine[mine["method"].isin(methods)] if methods else mine
    if len(mine) >= planned:
        return ""
    return (f"**Incomplete: {len(mine)} of the {planned} planned cells are stored** (its latest run was stopped "
            "or is still running; rerun `ilcforce study` on its file to finish it). Every number here is "
            "over the stored cells only.")


def _settings_text(results) -> str:
    """How the settings were chosen: the labels of a settings list, or the swept keys."""
    if getattr(results, "labelled", False):
        return (" listed by name (" + "; ".join(str(v) for v in results.settings["label"]) + ")"
                + (f", setting columns {', '.join(results.sweep_keys)}" if results.sweep_keys else ""))
    return f" over {', '.join(results.sweep_keys)}" if results.sweep_keys else ""


def count_text(n: int, noun: str) -> str:
    """'1 seed', '3 seeds'."""
    return f"{n} {noun}{'' if n == 1 else 's'}"


def _seed_text(seeds: list[int]) -> str:
    if not seeds:
        return "none"
    if seeds == list(range(seeds[0], seeds[-1] + 1)):
        return f"{seeds[0]}-{seeds[-1]}"
    return ", ".join(map(str, seeds[:10])) + (" ..." if len(seeds) > 10 else "")


def _index_lines(name: str, results, headline: pd.DataFrame, n_seeds: int, done: int, failed: int) -> list[str]:
    lines = [f"### [{name}](studies/{name}/report.md)", ""]
    if results.description:
        lines += [table_write.inert_markdown(results.description), ""]
    lines += [f"{count_text(n_seeds, 'seed')}, {len(results.settings)} setting(s), {done} cells done, {failed} failed.",
              ""]
    incomplete = incomplete_text(results)
    lines += [incomplete, ""] if incomplete else []
    if len(headline):
        what = "first setting" if results.sweep_keys else "verdicts over seeds"
        lines += [f"The paper's claims ({what}):", "",
                  table_write.markdown_table(headline[["claim", "verdict", "frequency", "statement"]]), ""]
    return lines


def study_index_section(reports: list[StudyReport]) -> list[str]:
    """The index's section on the studies (empty without studies), in the order of ``reports``."""
    section = []
    if reports:
        section = ["## Studies (over seeds)", "",
                   "Each study runs its methods over many seeds (and settings); its numbers are medians with "
                   "95% bootstrap intervals of the median and its verdicts are frequencies over seeds. Single-run reports follow below.",
                   ""]
        for report in reports:
            section += report.index_lines or [f"### {report.name}", "", "No report (see warnings).", ""]
    return section


def studies_provenance(found: dict[str, object]) -> str:
    """"studies run on 2026-12-05 at commit 0123456789ab" from the studies' recorded sessions."""
    commits, dates = set(), []
    for results in found.values():
        for session in getattr(results, "sessions", None) or []:
            if not isinstance(session, dict):
                continue
            commit = str((session.get("versions") or {}).get("git_commit") or "")
            if commit:
                commits.add(commit[:12])
            when = str(session.get("finished") or session.get("started") or "")
            if when:
                dates.append(when[:10])
    when = max(dates) if dates else datetime.now(timezone.utc).strftime("%Y-%m-%d")
    return f"studies run on {when}" + (f" at commit {', '.join(sorted(commits))}" if commits else "")
