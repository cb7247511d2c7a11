"""Tuning figures: a method's objective against the trial number (``ilcforce tune``).

Draws on the Axes it is given and returns the artists, as every report figure does; the input is
:func:`trials_frame`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes

from ilcforce.controllers import REGISTRY


def trials_frame(path) -> pd.DataFrame:
    """Every trial of the tuning store ``path`` that passes every check
    (:func:`ilcforce.tune.runner.read_trials`) as a tidy table, one row per (method, trial), in trial
    order: method, trial, state, objective (NaN when failed), best_so_far (the method's best up to
    and including this trial, NaN before the first complete one), message, elapsed (s), then one
    column per gain (dotted key; a vector gain holds a list)."""
    import math

    from ilcforce.tune.runner import read_trials

    rows = []
    for method, trials in read_trials(path).items():
        best = math.inf
        for number in sorted(trials):
            record = trials[number]
            value = record["value"] if record["state"] == "complete" else math.nan
            best = min(best, value) if value == value else best
            rows.append({"method": method, "trial": number, "state": record["state"], "objective": value,
                         "best_so_far": best if best < math.inf else math.nan, "message": record["message"],
                         "elapsed": record["elapsed"], **record["gains"]})
    return pd.DataFrame(rows, columns=None if rows else ["method", "trial", "state", "objective", "best_so_far",
                                                          "message", "elapsed"])


def plot_tuning_history(ax: Axes, frame: pd.DataFrame, method: str) -> list:
    """The objective of each complete trial (dots), the best so far (a step line), failed trials
    as crosses at the bottom, and trial 0 (the experiment's own gains) ringed."""
    rows = frame[frame["method"] == method].sort_values("trial")
    spec = REGISTRY.get(method)
    color = spec.color if spec is not None else None
    label = spec.label if spec is not None else method
    done = rows[rows["state"] == "complete"]
    artists = [ax.plot(done["trial"], done["objective"], "o", ms=3, color=color, alpha=0.6, label=f"{label}: trial")[0],
               ax.step(rows["trial"], rows["best_so_far"], where="post", color=color, label=f"{label}: best so far")[0]]
    failed = rows[rows["state"] != "complete"]
    if len(failed):  # at the axes' foot (x in trials, y as a fraction of the axes): never on the step line
        artists.append(ax.plot(failed["trial"], np.full(len(failed), 0.03), "x", color="0.4", clip_on=False,
                               transform=ax.get_xaxis_transform(), label="failed (diverged or invalid)")[0])
    first = rows[(rows["trial"] == 0) & (rows["state"] == "complete")]
    if len(first):
        artists.append(ax.plot(first["trial"], first["objective"], "o", ms=8, mfc="none", color=color,
                               label="trial 0: the experiment's gains")[0])
    if len(failed):  # a free band at the foot for the crosses, below every objective drawn
        low, high = ax.get_ylim()
        ax.set_ylim(low - 0.12 * (high - low), high)
    ax.set_xlabel("trial")
    ax.set_ylabel("objective (lower is better)")
    return artists


#: Significant digits of a chosen gain in the table: the search's resolution is far coarser (a
#: log-scaled range over decades), and 16 digits hid the value. The tuned experiment file keeps
#: every digit.
GAIN_DIGITS = 4
#: Method panels side by side in the history figure (one column of seven was 3,080 px tall).
HISTORY_COLUMNS = 2


def _gain(value) -> str:
    if isinstance(value, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_gain(v) for v in value) + "]"
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.{GAIN_DIGITS}g}"
    return str(value)


def history_figure(frame: pd.DataFrame, methods: list[str]):
    """One panel per method (:func:`plot_tuning_history`), HISTORY_COLUMNS to a row."""
    from matplotlib.figure import Figure

    columns = max(1, min(len(methods), HISTORY_COLUMNS))
    rows = -(-len(methods) // columns)
    fig = Figure(figsize=(4.8 * columns, 2.3 * rows + 0.3), layout="constrained")
    axes = fig.subplots(rows, columns, squeeze=False).ravel()
    for ax, method in zip(axes, methods):
        plot_tuning_history(ax, frame, method)
        ax.set_title(method, fontsize="medium")
    for ax in axes[len(methods):]:
        ax.set_visible(False)
    return fig


def tuning_table(frame: pd.DataFrame, budget: int) -> pd.DataFrame:
    """Per method: trials run of the budget, failed trials, trial 0's objective (the experiment's
    gains), the best objective and its trial, and the chosen gains (dotted key = value)."""
    rows = []
    gain_columns = [c for c in frame.columns if "." in c]
    for method, group in frame.groupby("method", sort=False):
        group = group.sort_values("trial")
        done = group[group["state"] == "complete"]
        first = group[group["trial"] == 0]
        best = done.loc[done["objective"].idxmin()] if len(done) else None
        chosen = "" if best is None else "; ".join(f"{c} = {_gain(best[c])}" for c in gain_columns
                                                   if c.startswith(f"{method}.") and best[c] is not None
                                                   and best[c] == best[c])
        rows.append({"method": method, "trials": f"{len(group)} of {budget}",
                     "failed": int((group["state"] != "complete").sum()),
                     "trial 0 objective": float(first["objective"].iloc[0]) if len(first) else float("nan"),
                     "best objective": float(best["objective"]) if best is not None else float("nan"),
                     "best trial": int(best["trial"]) if best is not None else -1, "chosen gains": chosen})
    return pd.DataFrame(rows)


def write_tuning_report(path, out_dir, formats: tuple[str, ...]) -> tuple[list, list[str]]:
    """``<out_dir>/<name>/index.md`` and ``history.<fmt>`` for the tuning store ``path``: the table of
    :func:`tuning_table` and the objective against the trial number per method. Returns (files,
    index lines). Raises TuningStoreError for a store that is not valid."""
    import json
    from pathlib import Path

    from ilcforce.report.figure_files import save_figure, write_text_whole
    from ilcforce.report.table_write import markdown_table, write_table
    from ilcforce.store.tuning import read_header
    from ilcforce.tune.runner import validate_tuning

    path, out_dir = Path(path), Path(out_dir)
    summary = validate_tuning(path)
    header = read_header(path)
    definition = json.loads(header["definition_json"])
    frame = trials_frame(path)
    name = summary["name"]
    target = out_dir / path.name  # a renamed copy of a store is its own page, not the original's
    target.mkdir(parents=True, exist_ok=True)
    files = []
    budget = _budget(header["tuning_toml"])
    methods = [m for m in definition["methods"] if m in set(frame["method"])] if len(frame) else []
    if methods:
        files += save_figure(history_figure(frame, methods), target, "history", formats)
    table = tuning_table(frame, budget) if len(frame) else pd.DataFrame()
    description = header.get("description", "")
    text = [f"# Tuning {name}" + (f" (the store {path.name})" if path.name != name else ""), "", *([description, ""] if description else []),
            f"Budget per method: {budget} trials (trial 0 = the experiment's gains) x {len(definition['seeds'])} "
            f"seeds x {definition['iterations']} iterations; objective {definition['objective']!r} over iterations "
            f"{definition['score_iterations'] - definition['score_last']}..{definition['score_iterations'] - 1} "
            "(lower is better; a divergence anywhere fails the trial).", ""]
    if len(table):
        files += write_table(table, target, "tuning")  # tuning.csv beside the page: the verdict as data
        text += [markdown_table(table), ""]
        text += [f"![objective against trial](history.{formats[0]})", "",
                 "One panel per method: a dot is a complete trial's objective, the step line the best so far, the "
                 "ringed dot trial 0 (the experiment's own gains), a cross at the foot of the panel a failed trial "
                 "(a seed diverged somewhere in the horizon, or gains the setting refuses). The objective is "
                 "log10(e_P / 1 mm) + log10(e_F / 1 N) of the settled error norms (or one of the two terms), median "
                 "over seeds: one unit lower is a tenfold smaller error.", ""] if methods and formats else []
    files.append(write_text_whole(target / "index.md", "\n".join(text)))
    line = f"- [tuning {path.name}](tuning/{path.name}/index.md): " + ", ".join(
        f"{row['method']} {row['trial 0 objective']:.3g} -> {row['best objective']:.3g}" for _, row in table.iterrows())
    return files, [line]


def _budget(tuning_toml: str) -> int:
    import tomllib

    try:
        return int(tomllib.loads(tuning_toml)["tune"]["trials"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError):
        return -1


def tuning_pages(results_dir: Path, out_dir: Path, formats: tuple[str, ...], written: list,
                  warnings: list) -> list[str]:
    """The page of every tuning store under ``results/tuning/`` (:mod:`ilcforce.report.tuning`);
    index lines. A store that is not valid is a warning line, never the end of the report."""
    from ilcforce.report.figures import report_style
    from ilcforce.store.tuning import TuningStoreError, is_tuning_store

    folder = results_dir / "tuning"
    lines: list[str] = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        if not is_tuning_store(path):
            continue
        try:
            with report_style():
                files, index_lines = write_tuning_report(path, out_dir / "tuning", formats)
        except (TuningStoreError, ValueError, KeyError) as error:
            warnings.append(f"{path}: tuning page not written: {' '.join(str(error).split())}")
            continue
        written += files
        lines += index_lines
    return lines
