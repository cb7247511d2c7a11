"""Figures of a study: Figs. 3 and 4 with bands over seeds, key numbers against a swept value (or
against the labels of a settings list), and a heatmap of the first diverged iteration over a 2-D sweep.

Bands: the dark band is the 95% percentile-bootstrap interval of the median over seeds (the
uncertainty of the line drawn); the light band holds the central 95% of the seeds (2.5th to 97.5th
percentile: the spread a single seed shows). Seeds without a value (diverged) are left out.
Figures are built without pyplot and saved here; call inside ``report_style()``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ilcforce.config_units import axis_label
from ilcforce.records import STATUS_DIVERGED
from ilcforce.report import table_write, tables
from ilcforce.report.figure_files import save_figure
from ilcforce.report.figure_style import method_color, method_text
from ilcforce.stats import median_interval

BAND_CAPTION = ("Line: median over seeds. Dark band: 95% percentile-bootstrap interval of that median. "
                "Light band: central 95% of the seeds (2.5th-97.5th percentile). A seed that diverged "
                "leaves the median from its divergence on (the legend gives the seeds counted at the end).")


def _bands(values: np.ndarray) -> tuple[float, float, float, float, float, int]:
    """median, CI low, CI high, 2.5%, 97.5% and n of the finite ``values``."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return (math.nan,) * 5 + (0,)
    iv = median_interval(finite)
    lo, hi = np.percentile(finite, [2.5, 97.5])
    return iv.estimate, iv.low, iv.high, float(lo), float(hi), int(finite.size)


def _log_scale(ax, drawn: list[np.ndarray]) -> None:
    """Log y when every value drawn is positive (a log axis cannot show 0 or an empty plot)."""
    values = np.concatenate([np.ravel(d) for d in drawn]) if drawn else np.array([])
    values = values[np.isfinite(values)]
    if values.size and np.all(values > 0):
        ax.set_yscale("log")


#: What the two shades of a band are, for the legend of every band figure.
DARK_BAND = "dark band: 95% interval of the median"
LIGHT_BAND = "light band: central 95% of the seeds"


def band_legend_entries(ax) -> None:
    """Add the two band shades (in grey) to ``ax``'s legend entries, so the legend says what they are."""
    ax.fill_between([], [], [], color="0.3", alpha=0.35, linewidth=0, label=DARK_BAND)
    ax.fill_between([], [], [], color="0.3", alpha=0.12, linewidth=0, label=LIGHT_BAND)


def _bar_legend_entries(ax) -> None:
    """The same for the bars of unordered settings (thick: interval of the median; thin: seeds)."""
    ax.vlines([], [], [], color="0.3", linewidth=4.0, alpha=0.8, label="thick bar: 95% interval of the median")
    ax.vlines([], [], [], color="0.3", linewidth=1.0, alpha=0.45, label="thin bar: central 95% of the seeds")


def _band_plot(ax, x, stats, method: str, label: str) -> np.ndarray:
    stats = np.asarray(stats, dtype=float).reshape(-1, 6)
    color = method_color(method)
    ax.fill_between(x, stats[:, 3], stats[:, 4], color=color, alpha=0.12, linewidth=0)
    ax.fill_between(x, stats[:, 1], stats[:, 2], color=color, alpha=0.35, linewidth=0)
    ax.plot(x, stats[:, 0], marker="o", markersize=3, color=color, label=label)
    return stats[:, :5]


def _category_plot(ax, x, stats, method: str, label: str, offset: float) -> np.ndarray:
    """Bands for unordered settings (a settings list): no line joins two settings; per setting a
    marker at the median, a thick bar for its 95% interval and a thin bar for the central 95%."""
    stats = np.asarray(stats, dtype=float).reshape(-1, 6)
    color = method_color(method)
    xs = np.asarray(x, dtype=float) + offset
    ax.vlines(xs, stats[:, 3], stats[:, 4], color=color, alpha=0.45, linewidth=1.0)
    ax.vlines(xs, stats[:, 1], stats[:, 2], color=color, linewidth=4.0, alpha=0.8)
    ax.plot(xs, stats[:, 0], marker="o", markersize=5, linestyle="none", color=color, label=label)
    return stats[:, :5]


def norm_band_figure(frame: pd.DataFrame, column: str, ylabel: str, title: str,
                     flags: Mapping[str, str] | None = None, perturbation_iteration: int | None = None,
                     perturbation_label: str = "m3 x 1.4") -> Figure:
    """One error 2-norm of ONE setting against iteration: median and bands per method, and a
    dashed line at the plant's change (``perturbation_iteration``, labelled ``perturbation_label``)."""
    methods = tables.ordered_methods(frame["method"].unique().tolist())
    n_seeds = frame["seed"].nunique()
    fig = Figure(figsize=(8.8, 4.0))
    ax = fig.add_subplot()
    drawn = []
    for method in methods:
        wide = frame[frame["method"] == method].pivot(index="iteration", columns="seed", values=column)
        wide = wide.sort_index()
        stats = [_bands(wide.loc[j].to_numpy(dtype=float)) for j in wide.index]
        n_end = stats[-1][5] if stats else 0
        label = method_text(method) + (" (unstable learning)" if flags and method in flags else "")
        label += f", {n_end} of {n_seeds} seeds" if n_end != n_seeds else ""
        drawn.append(_band_plot(ax, wide.index.to_numpy(), stats, method, label))
    _log_scale(ax, drawn)
    last = int(frame["iteration"].max()) if len(frame) else 0
    if perturbation_iteration is not None and 0 < perturbation_iteration <= last:
        ax.axvline(perturbation_iteration, color="0.4", linestyle="--", linewidth=1.0,
                   label=f"{perturbation_label} from j = {perturbation_iteration}")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration j")
    ax.set_ylabel(ylabel)
    ax.set_title(f"{title} over {n_seeds} seeds")
    band_legend_entries(ax)
    ax.legend(fontsize="small", title="line: median over seeds", title_fontsize="small", loc="upper left",
              bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    return fig


def norm_band_figures(frame: pd.DataFrame, directory: Path, tag: str, formats: tuple[str, ...],
                      flags: Mapping[str, str] | None = None, perturbation_iteration: int | None = None,
                      perturbation_label: str = "m3 x 1.4") -> list[Path]:
    """Figs. 3 and 4 of ONE setting (:func:`norm_band_figure`), saved."""
    written = []
    for stem, column, ylabel in (("fig3_position_error_norm", "position_error_2norm", "position error 2-norm (m)"),
                                 ("fig4_force_error_norm", "force_error_2norm", "force error 2-norm (N)")):
        fig = norm_band_figure(frame, column, ylabel, "Fig. 3" if stem.startswith("fig3") else "Fig. 4", flags,
                               perturbation_iteration, perturbation_label)
        written += save_figure(fig, directory, f"{stem}_{tag}", formats)
    return written


def _sweep_numbers(frame: pd.DataFrame, iterations: int) -> dict[str, tuple[str, callable]]:
    last = iterations - 1
    first = max(0, last - 4)
    window = f"mean j = {first}..{last}"

    def window_mean(column):
        def get(m: pd.DataFrame) -> float:
            values = [float(m.loc[j, column]) if j in m.index else math.nan for j in range(first, last + 1)]
            return float(np.mean(values)) if all(math.isfinite(v) for v in values) else math.nan
        return get

    def at_last(column):
        return lambda m: float(m.loc[last, column]) if last in m.index and column in m.columns else math.nan

    # the L2 norm (sqrt(dt sum e^2)), not the paper's 2-norm: the 2-norm grows with the number of log
    # samples, so it would change with a swept sample time or log_every even for the same error
    return {
        "position": (f"position error L2, {window} (m s^1/2)", window_mean("position_error_l2")),
        "force": (f"force error L2, {window} (N s^1/2)", window_mean("force_error_l2")),
        # settled (t >= 20 ms), as the stability test reads H (claim 5 judges the whole grid's, the paper's
        # definition): the whole grid's H is set by the start mismatch at t = 0
        "chattering_y": (f"H y settled (t >= 20 ms) at j = {last} (N)", at_last("chattering_task_y_settled")),
    }


def _first_diverged(m: pd.DataFrame) -> float:
    diverged = m.index[m["status"].astype(str) == STATUS_DIVERGED]
    return float(diverged[0]) if len(diverged) else math.nan


def _tag(value) -> str:
    """A swept value as a label (numpy scalars as their Python value)."""
    return str(value.item() if isinstance(value, np.generic) else value)


def _numeric(values: list) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)


def _iterations(results) -> int:
    import json

    try:
        return int(json.loads(results.settings["config_json"].iloc[0])["experiment"]["iterations"])
    except (ValueError, KeyError, TypeError, IndexError):
        return int(results.metrics["iteration"].max()) + 1


def sweep_figures(results, directory: Path, formats: tuple[str, ...]) -> tuple[list[Path], list[str]]:
    """1-D sweep or a settings list: key numbers against the swept value (against the setting's
    label for a list) with bands; 2-D sweep: heatmaps of the first diverged iteration per method.
    Returns the files and the report's lines."""
    keys = list(results.sweep_keys)
    frame = results.metrics
    methods = tables.ordered_methods(frame["method"].unique().tolist())
    iterations = _iterations(results)
    per_cell: dict[tuple[int, str], dict[int, pd.DataFrame]] = {}
    for setting in results.settings["setting"]:
        mine = results.setting_metrics(int(setting))
        for method in methods:
            per_cell[(int(setting), method)] = {int(s): f.set_index("iteration").sort_index()
                                                for s, f in mine[mine["method"] == method].groupby("seed")}
    files: list[Path] = []
    lines: list[str] = []
    divergence_rows = []
    labelled = bool(getattr(results, "labelled", False))
    for k in results.settings["setting"]:
        row = ({"setting": results.settings.loc[k, "label"]} if labelled
               else {key: results.settings.loc[k, key] for key in keys})
        for method in methods:
            seeds = per_cell[(int(k), method)]
            firsts = np.array([_first_diverged(m) for m in seeds.values()])
            diverged = int(np.isfinite(firsts).sum())  # not k: the setting's index, used again for the next method
            row[method] = (f"j = {int(np.nanmin(firsts))} ({diverged} of {len(seeds)} seeds)" if diverged
                           else f"stable through {iterations - 1} ({len(seeds)} seeds)")
        divergence_rows.append(row)
    lines += ["### First diverged iteration (earliest over seeds; how many seeds diverged)", "",
              table_write.markdown_table(pd.DataFrame(divergence_rows)), ""]
    if labelled or len(keys) == 1:
        # a settings list is drawn against its labels (categorical), a 1-D sweep against its values
        key = "setting" if labelled else keys[0]
        column = results.settings["label"] if labelled else results.settings[key]
        values = [v.item() if isinstance(v, np.generic) else v for v in column]
        numeric = not labelled and _numeric(values)
        x = np.asarray(values, dtype=float) if numeric else np.arange(len(values), dtype=float)
        numbers = _sweep_numbers(frame, iterations)
        fig = Figure(figsize=(8.8, 2.8 * len(numbers)))
        axes = fig.subplots(len(numbers), 1, sharex=True)
        missing_drawn = False
        for ax, (_name, (ylabel, get)) in zip(axes, numbers.items()):
            drawn, missing = [], []
            for n, method in enumerate(methods):
                stats = [_bands(np.array([get(m) for m in per_cell[(k, method)].values()], dtype=float))
                         for k in range(len(values))]
                if labelled:
                    offset = 0.12 * (n - (len(methods) - 1) / 2)
                    drawn.append(_category_plot(ax, x, stats, method, method_text(method), offset))
                else:
                    drawn.append(_band_plot(ax, x, stats, method, method_text(method)))
                # a setting where no seed has the number (every seed diverged before it) is marked,
                # not silently left out of the line
                gone = [float(x[i]) for i, row in enumerate(stats) if not math.isfinite(row[0])]
                missing += [(xi, method) for xi in gone]
            ax.set_ylabel(ylabel, fontsize="small")
            _log_scale(ax, drawn)
            for xi, method in missing:  # at the axes' foot (y as a fraction of the axes)
                ax.plot([xi], [0.04], marker="x", markersize=7, color=method_color(method), linestyle="none",
                        transform=ax.get_xaxis_transform(), clip_on=False)
            missing_drawn = missing_drawn or bool(missing)
        if numeric and min(values) > 0 and max(values) / min(values) >= 10:
            axes[-1].set_xscale("log")
        if not numeric:
            axes[-1].set_xticks(x, [str(v) for v in values], rotation=20 if labelled else 0,
                                ha="right" if labelled else "center")
            for ax in axes:
                ax.set_xlim(-0.5, len(values) - 0.5)
        axes[-1].set_xlabel(key if labelled else axis_label(key))
        (_bar_legend_entries if labelled else band_legend_entries)(axes[0])
        if missing_drawn:
            axes[0].plot([], [], marker="x", color="0.3", linestyle="none",
                         label="cross at the foot: no seed has the number (all diverged)")
        # one legend for the panels, below them across the figure's width (on the right of the top panel it
        # left a blank block of the legend's width beside the panels under it)
        handles, texts = axes[0].get_legend_handles_labels()
        fig.legend(handles, texts, fontsize="small", title=f"{'marker' if labelled else 'line'}: median over seeds",
                   title_fontsize="small", loc="outside lower center", ncols=min(3, len(texts)))
        axes[0].set_title(f"key numbers {'per setting' if labelled else 'against ' + key}; "
                          "seeds that diverged are left out")
        files += save_figure(fig, directory, "sweep_key_numbers", formats)
        caption = BAND_CAPTION if not labelled else (
            "Marker: median over seeds. Thick bar: 95% percentile-bootstrap interval of that median. Thin bar: "
            "central 95% of the seeds. The settings are listed, not ordered, so no line joins them.")
        lines += ["![sweep_key_numbers](sweep_key_numbers.png)", "", caption + " Error norms here are the "
                  "grid-independent L2 norms sqrt(dt sum_k e(t_k)^2): the paper's 2-norm grows with the number of "
                  "log samples, so it is not comparable across settings whose grids differ.", ""]
    else:
        first, second = keys[0], keys[1]
        v1 = list(dict.fromkeys(_tag(v) for v in results.settings[first]))
        v2 = list(dict.fromkeys(_tag(v) for v in results.settings[second]))
        fig = Figure(figsize=(4.2 * len(methods), 3.8))
        axes = np.atleast_1d(fig.subplots(1, len(methods)))
        for ax, method in zip(axes, methods):
            grid = np.full((len(v1), len(v2)), np.nan)
            text = [["" for _ in v2] for _ in v1]
            for setting in results.settings.itertuples(index=False):
                i = v1.index(_tag(results.settings.loc[setting.setting, first]))
                j = v2.index(_tag(results.settings.loc[setting.setting, second]))
                seeds = per_cell[(int(setting.setting), method)]
                firsts = np.array([_first_diverged(m) for m in seeds.values()])
                k = int(np.isfinite(firsts).sum())
                if k:
                    grid[i, j] = np.nanmin(firsts)
                    text[i][j] = f"j = {int(grid[i, j])}\n{k}/{len(seeds)} seeds"
                else:
                    grid[i, j] = iterations  # drawn as "beyond the last iteration"
                    text[i][j] = f"stable\nthrough {iterations - 1}"
            image = ax.imshow(grid, origin="lower", aspect="auto", cmap="viridis", vmin=0, vmax=iterations)
            for i in range(len(v1)):
                for j in range(len(v2)):
                    light = grid[i, j] > 0.6 * iterations  # dark text on the bright end of viridis
                    ax.text(j, i, text[i][j], ha="center", va="center", fontsize="x-small",
                            color="black" if light else "white")
            ax.grid(False)
            ax.set_xticks(range(len(v2)), v2, fontsize="small")
            ax.set_yticks(range(len(v1)), v1, fontsize="small")
            ax.set_xlabel(axis_label(second))
            ax.set_ylabel(axis_label(first))
            ax.set_title(f"{method_text(method)}: first diverged iteration", fontsize="small")
        fig.colorbar(image, ax=list(axes), label="earliest diverged iteration over seeds")
        files += save_figure(fig, directory, "sweep_divergence_heatmap", formats)
        extra = f" ({', '.join(keys[2:])} pooled)" if len(keys) > 2 else ""
        lines += ["![sweep_divergence_heatmap](sweep_divergence_heatmap.png)", "",
                  f"Earliest diverged iteration over seeds per cell of the {first} x {second} grid{extra}, "
                  f"with the number of seeds that diverged; \"stable through N\" where none did.", ""]
    return files, lines
