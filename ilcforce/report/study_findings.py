"""Findings of a study: per setting, the claims part by part over seeds, the
learning-stability flags, the first diverged iteration, and the key numbers with intervals; for a
one-key sweep, the stability boundary as a figure.

Reads a :class:`ilcforce.study.tidy.StudyResults`; writes nothing itself except through
:func:`write_study_findings`.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ilcforce.config_units import axis_label
from ilcforce.records import STATUS_DIVERGED, task_axes
from ilcforce import stability
from ilcforce.report import calibration, claim_map, claim_parts, equal_chattering
from ilcforce.report import claims as claims_module
from ilcforce.report import figure_style, figures, paper
from ilcforce.report.figure_files import save_figure, write_text_whole
from ilcforce.report.study import incomplete_text, setting_iterations, setting_perturbation
from ilcforce.report import verdicts as verdict_rows
from ilcforce.report.table_write import inert_markdown, markdown_table, write_csv, write_table
from ilcforce.stats import format_interval, median_interval

#: Key numbers per setting and method, read at the paper's Table 3 iteration (j = 19, or the setting's
#: last iteration when it runs fewer): grid-independent error norms (comparable across sample times) and H,
#: those of them a study's frame has: H per task axis (x, y of a 2-axis task; u, v, n of a 3-axis one) and
#: H settled on the wall's normal (y; n).
KEY_COLUMNS = (("position_error_l2", "|e_P| L2 (m s^1/2)"), ("force_error_l2", "|e_F| L2 (N s^1/2)"),
               ("position_error_2norm", "|e_P| 2-norm (m)"), ("force_error_2norm", "|e_F| 2-norm (N)"),
               ("chattering_task_x", "H_x (N)"), ("chattering_task_y", "H_y (N)"),
               ("chattering_task_y_settled", "H_y settled (N)"),
               *((f"chattering_task_{axis}", f"H_{axis} (N)") for axis in task_axes(3)),
               (f"chattering_task_{task_axes(3)[-1]}_settled", f"H_{task_axes(3)[-1]} settled (N)"))


def first_divergence(frame: pd.DataFrame) -> pd.DataFrame:
    """Per (seed, method): the first diverged iteration (NaN when none) and the iterations run."""
    rows = []
    for (seed, method), cell in frame.groupby(["seed", "method"], sort=False):
        diverged = cell.loc[cell["status"].astype(str) == STATUS_DIVERGED, "iteration"]
        rows.append({"seed": seed, "method": method, "iterations": int(cell["iteration"].max()) + 1,
                     "diverged_at": float(diverged.min()) if len(diverged) else math.nan})
    return pd.DataFrame(rows, columns=["seed", "method", "iterations", "diverged_at"])


#: Up to this many diverged seeds, their first diverged iterations are listed rather than summarised:
#: a median with a bootstrap interval over two or three values is only their middle and their range.
LIST_AT_MOST = 4


def _divergence_text(div: pd.DataFrame) -> str:
    k, n = int(div["diverged_at"].notna().sum()), len(div)
    if k == 0:
        return f"stable through j = {int(div['iterations'].max()) - 1} (0 of {n})"
    if k <= LIST_AT_MOST:
        firsts = ", ".join(str(int(j)) for j in sorted(div["diverged_at"].dropna()))
        return f"j = {firsts} ({k} of {n} seeds)"
    return f"j = {format_interval(median_interval(div['diverged_at']))} ({k} of {n} seeds)"


def _task_loss_text(per_method: pd.DataFrame, perturbation_iteration: int) -> str:
    """"; fails the task in k of n seeds" (seeds that completed but lost the task after the plant's
    change, :func:`ilcforce.report.tables.task_loss`), or "" when none did."""
    from ilcforce.report.tables import FAILS_THE_TASK, divergence, task_loss

    seeds = [cell.set_index("iteration").sort_index() for _seed, cell in per_method.groupby("seed", sort=False)]
    lost = sum(1 for cell in seeds if divergence(cell) is None and task_loss(cell, perturbation_iteration))
    return f"; {FAILS_THE_TASK} in {lost} of {len(seeds)}" if lost else ""


def setting_rows(frame: pd.DataFrame, *, perturbation_iteration: int, iterations: int,
                 deterministic: bool = False, config: dict | None = None
                 ) -> tuple[list[dict], pd.DataFrame, dict, pd.DataFrame]:
    """One setting's per-method rows (key numbers, divergence, flag), its claim parts, flags, and its
    growth frame (empty: the stability test could not run). A deterministic setting (no noise
    source active) is one evaluation: its first seed alone."""
    if deterministic:
        frame = claims_module.first_seed_only(frame)
    parts = claims_module.judge_claims_over_seeds(frame, perturbation_iteration=perturbation_iteration,
                                                  deterministic=deterministic, config=config)
    growth = stability.learning_growth(frame, perturbation_iteration=perturbation_iteration, config=config)
    flags = stability.unstable_methods(growth)
    fitted = set(growth["method"].astype(str))
    divergence = first_divergence(frame)
    j_key = min(paper.CHATTERING_ITERATION, iterations - 1)
    rows = []
    for method, per_method in frame.groupby("method", sort=False):
        row = {"method": method, "divergence": _divergence_text(divergence[divergence["method"] == method])
               + _task_loss_text(per_method, perturbation_iteration),
               "unstable learning": (flags.get(str(method), "no").split(": ", 1)[-1] if str(method) in fitted
                                     else stability.NOT_FITTED)}
        for column, label in KEY_COLUMNS:
            if column not in per_method.columns:
                continue
            at = per_method[(per_method["iteration"] == j_key) & (per_method["status"].astype(str) == "complete")]
            row[f"{label} at j = {j_key}"] = format_interval(median_interval(at[column]))
        rows.append(row)
    return rows, parts, flags, growth


def _setting_name(values: dict) -> str:
    return ", ".join(f"{k} = {v:g}" if isinstance(v, float) else f"{k} = {v}" for k, v in values.items()) or "-"


#: The columns a breakdown over listed settings shows (labels of KEY_COLUMNS) and their
#: short names: the error 2-norms, and H_y on the whole grid beside H_y settled (what the start
#: mismatch does to H, the initial-velocity study's question).
ERROR_LABELS = {"|e_P| 2-norm (m)": "|e_P|", "|e_F| 2-norm (N)": "|e_F|", "H_y (N)": "H_y",
                "H_y settled (N)": "H_y settled", "H_n (N)": "H_n", "H_n settled (N)": "H_n settled"}


def error_table(settings: dict) -> list[str]:
    """For a study with a settings list (a breakdown, e.g. by noise source): each method's error
    2-norms per setting, median [95% bootstrap interval of the median] over seeds, so the settings
    can be compared."""
    rows, ats = [], set()
    for setting, entry in settings.items():
        row: dict[str, object] = {"setting": setting}
        for method_row in entry["rows"]:
            for label, short in ERROR_LABELS.items():
                key = next((k for k in method_row if k.startswith(label + " at j = ")), None)
                if key is not None:
                    ats.add(key.removeprefix(label + " at j = "))
                    row[f"{method_row['method']} {short}"] = method_row[key]
        rows.append(row)
    if len(rows) < 2 or len(rows[0]) < 2:
        return []
    # key numbers are read at j = 19, or at a shorter setting's last iteration
    at = f" at j = {ats.pop()}" if len(ats) == 1 else f" at j = {', '.join(sorted(ats, key=int))} (each setting's)"
    normal = "H_n" if any(str(k).endswith((" H_n", " H_n settled")) for row in rows for k in row) else "H_y"
    return ["", f"Error 2-norms and {normal} (whole grid and settled, t >= 20 ms){at} per setting (median [95% "
            "bootstrap interval of the median] over seeds; |e_P| in m, |e_F| and H in N):", "",
            markdown_table(pd.DataFrame(rows))]


def study_markdown(results) -> tuple[str, dict, pd.DataFrame, pd.DataFrame]:
    """The study's findings page, a summary for the README (setting -> per-method rows and seeds),
    and its verdicts as rows (``claims.csv``, ``stability.csv``: :mod:`ilcforce.report.verdicts`).
    Each setting is judged with its own perturbation iteration and number of iterations (its
    configuration)."""
    lines = [f"# Study `{results.name}`", "", f"**{inert_markdown(results.description) or 'no description'}**", ""]
    incomplete = incomplete_text(results)
    lines += [incomplete, ""] if incomplete else []
    lines += ["Every number is a median over seeds with the 95% percentile-bootstrap interval of the median; divergence "
              "counts the seeds whose run diverged. Claims follow the rule of the single-run reports "
              "(a claim fails when no central part holds, and holds in part when some do; it is uncertain where the interval of a "
              "median crosses its threshold and leaves the verdict open); unstable learning follows the stated growth test.", ""]
    overview, summary, body = [], {}, []
    claim_tables, stability_tables = [], []
    for setting in results.settings.index:
        values = {k: results.settings.loc[setting, k] for k in results.sweep_keys}
        frame = results.setting_metrics(int(setting))
        if frame.empty:
            continue
        config_json = str(results.settings.loc[setting, "config_json"])
        deterministic = claims_module.is_deterministic(_config(config_json))
        rows, parts, flags, growth = setting_rows(frame, perturbation_iteration=setting_perturbation(config_json),
                                                  iterations=setting_iterations(config_json),
                                                  deterministic=deterministic, config=_config(config_json))
        verdicts = claims_module.claim_summary(parts)
        # a listed setting is named by its label (its key values are in the study report and the table)
        name = (str(results.settings.loc[setting, "label"]) if getattr(results, "labelled", False)
                else _setting_name(values))
        claim_tables.append(verdict_rows.claim_rows(parts, source=verdict_rows.STUDY, name=results.name,
                                                    setting=name))
        stability_tables.append(verdict_rows.stability_rows(growth, source=verdict_rows.STUDY, name=results.name,
                                                            setting=name))
        entry = {"setting": name}
        entry.update({f"claim {r.claim}": f"{r.verdict}" for r in verdicts.itertuples(index=False)})
        entry["unstable learning"] = ", ".join(flags) or ("none" if len(growth) else stability.NOT_FITTED)
        overview.append(entry)
        summary[name] = {"rows": rows, "seeds": int(frame["seed"].nunique()), "deterministic": deterministic}
        body += [f"## Setting: {name}", "", markdown_table(pd.DataFrame(rows))]
        body.append(markdown_table(verdicts[["claim", "verdict", "frequency", "parts", "statement"]]))
    if overview:
        overview_frame = pd.DataFrame(overview)
        seeds = {name: ("1 (deterministic)" if entry["deterministic"] else entry["seeds"])
                 for name, entry in summary.items()}
        overview_frame.insert(1, "seeds", overview_frame["setting"].map(seeds))
        lines += ["## Overview", "", markdown_table(overview_frame)]
    if getattr(results, "labelled", False):
        lines += error_table(summary)
    lines += body
    claims_frame = (pd.concat(claim_tables, ignore_index=True) if claim_tables
                    else pd.DataFrame(columns=verdict_rows.CLAIM_COLUMNS))
    stability_frame = (pd.concat(stability_tables, ignore_index=True) if stability_tables
                       else pd.DataFrame(columns=verdict_rows.STABILITY_COLUMNS))
    return "\n".join(lines) + "\n", summary, claims_frame, stability_frame


def _config(config_json: str) -> dict:
    try:
        loaded = json.loads(config_json)
    except ValueError:
        return {}
    return loaded if isinstance(loaded, dict) else {}


def figure_boundary(results) -> Figure | None:
    """For a one-key numeric sweep: (a) first diverged iteration per method against the swept
    value (median over the seeds that diverged, bars from min to max; a hollow marker at the top
    means stable through the last iteration in every seed), (b) the growth rate per iteration of
    H_x settled (t >= 20 ms) per method with its 95% interval, and 1 (no growth) dashed."""
    if len(results.sweep_keys) != 1 or getattr(results, "labelled", False):
        return None
    key = results.sweep_keys[0]
    xs = [results.settings.loc[s, key] for s in results.settings.index]
    if not all(isinstance(x, (int, float)) for x in xs):
        return None
    fig = Figure(figsize=(7.0, 6.0), layout="constrained")
    ax_div, ax_rate = fig.subplots(2, 1, sharex=True)
    methods = list(dict.fromkeys(results.metrics["method"]))
    offsets = {m: 1 + 0.06 * (k - (len(methods) - 1) / 2) for k, m in enumerate(methods)}
    top, rates_drawn = 0, 0
    for method in methods:
        color = figure_style.method_color(method)
        for setting, x in zip(results.settings.index, xs, strict=True):
            frame = results.setting_metrics(int(setting))
            frame = frame[frame["method"] == method]
            if frame.empty:
                continue
            div = first_divergence(frame)
            top = max(top, int(div["iterations"].max()))
            hit = div["diverged_at"].dropna()
            xm = x * offsets[method]
            if len(hit):
                med = float(np.median(hit))
                ax_div.errorbar([xm], [med], yerr=[[med - hit.min()], [hit.max() - med]], marker="o", color=color,
                                capsize=3, label=None)
                ax_div.annotate(f"{len(hit)}/{len(div)}", (xm, med), textcoords="offset points", xytext=(4, 4),
                                fontsize="x-small", color=color)
            else:
                ax_div.plot([xm], [div["iterations"].max()], marker="^", markerfacecolor="none", color=color)
            p = setting_perturbation(str(results.settings.loc[setting, "config_json"]))
            growth = stability.learning_growth(frame, perturbation_iteration=p, config=json.loads(
                str(results.settings.loc[setting, "config_json"])))
            hx = growth[growth["quantity"] == "chattering_task_x_settled"]
            if len(hx):
                r = hx.iloc[0]
                rates_drawn += 1
                ax_rate.errorbar([xm], [r.rate], yerr=[[r.rate - r.rate_low], [r.rate_high - r.rate]], marker="o",
                                 color=color, capsize=3)
        ax_div.plot([], [], marker="o", color=color, label=figures.method_label(method))
    ax_div.plot([], [], marker="^", markerfacecolor="none", color="0.3", linestyle="none",
                label="stable in every seed (at the iterations run)")
    ax_div.set_ylabel("first diverged iteration j")
    ax_div.set_ylim(-0.5, top + 1)
    ax_div.legend(fontsize="small")
    ax_div.yaxis.set_major_locator(MaxNLocator(integer=True))  # iterations: no tick at 2.5
    ax_rate.axhline(1.0, color="0.4", linestyle="--", linewidth=1.0)
    ax_rate.set_ylabel("growth rate of settled H_x per iteration")
    if not rates_drawn:  # an empty panel says nothing: the figure is (a) alone, and its title says why
        ax_rate.remove()
        ax_div.set_subplotspec(ax_div.get_subplotspec().get_gridspec()[:, 0])  # (a) takes the whole figure
        ax_rate = ax_div
        ax_div.xaxis.set_tick_params(labelbottom=True)
        ax_div.set_title(f"Stability boundary over {key}\n(growth rate of settled H_x: {stability.NOT_FITTED})",
                         fontsize="medium")
        fig.set_size_inches(7.0, 3.6)
    ax_rate.set_xlabel(axis_label(key))  # with its unit
    if min(xs) > 0:
        ax_rate.set_xscale("log")
        ax_rate.set_xlim(min(xs) / 1.5, max(xs) * 1.5)
    else:
        span = max(xs) - min(xs) or 1.0
        ax_rate.set_xlim(min(xs) - 0.1 * span, max(xs) + 0.1 * span)
    if rates_drawn:
        ax_div.set_title(f"Stability boundary over {key}")
    return fig


def write_study_findings(study_store: Path, out_dir: Path) -> tuple[list[Path], str, dict]:
    """Write ``out_dir/<name>/findings.md``, ``claims.csv`` and ``stability.csv`` (+ the boundary
    figure for 1-key sweeps)."""
    from ilcforce.study.tidy import read_study

    results = read_study(study_store)
    name = Path(study_store).stem  # the file's own name: a renamed copy of a store is a page of its own
    directory = Path(out_dir) / name
    directory.mkdir(parents=True, exist_ok=True)
    text, summary, claims_frame, stability_frame = study_markdown(results)
    written = [write_csv(claims_frame, directory / "claims.csv"), write_csv(stability_frame, directory / "stability.csv")]
    with figures.report_style():
        fig = figure_boundary(results)
        if fig is not None:
            [path] = save_figure(fig, directory, "fig_stability_boundary", ("png",))
            written.append(path)
            text += f"\n![stability boundary]({path.name})\n"
    extra: dict = {}
    if claim_map.is_claim_map_study(results):
        names = {}
        for setting in results.settings.index:
            values = {k: results.settings.loc[setting, k] for k in results.sweep_keys}
            names[_setting_name(values)] = tuple(float(values[k]) for k in claim_map.KEYS)
        seeds = {name: (1 if entry["deterministic"] else entry["seeds"]) for name, entry in summary.items()}
        rows = claim_map.claim_map(claims_frame, {n: v for n, v in names.items() if n in summary}, seeds)
        statements = {c.number: c.statement for c in claim_parts.CLAIMS}
        files, lines = claim_map.write_claim_map(rows, directory, statements)
        written += files
        text += "\n" + "\n".join(lines)
        extra["claim_map_sentence"] = claim_map.sentence(rows)
        extra["claim_map_seeds"] = int(max(seeds.values(), default=0))
    if calibration.is_calibration_study(results):
        files, lines, found = calibration.write_calibration(results, directory)
        written += files
        text += "\n" + "\n".join(lines)
        extra["calibration_text"] = found.summary() if found is not None else ""
        extra["calibration_scale"] = found.scale if found is not None else math.nan
    table, sentence = equal_chattering.comparison(results)
    if len(table):
        written += write_table(table, directory, "equal_chattering")
        text += ("\n## At equal chattering\n\n" + equal_chattering.__doc__.split("\n\n")[1].replace("\n", " ")
                 + "\n\n" + markdown_table(table) + "\n\n" + sentence[0].upper() + sentence[1:] + "\n")
        extra["equal_chattering_text"] = sentence
        extra["tuning_source"] = equal_chattering.tuning_of(results)["source"]
    write_text_whole(directory / "findings.md", text)
    written.append(directory / "findings.md")
    return written, name, {**extra, "description": inert_markdown(results.description), "settings": summary,
                                   "incomplete": incomplete_text(results),
                                   "labelled": bool(getattr(results, "labelled", False)),
                                   "claim_rows": claims_frame.to_dict("list"),
                                   "stability_rows": stability_frame.to_dict("list")}
