"""Figs. 5-7 over seeds: bands over the seeds of a study.

Figs. 5-7 of a single run draw time signals: Fig. 5 the position error X and force error Y against
t at j = 0, 5, 10, 15; Figs. 6/7 the control input and Delta tau = tau_d - tau against t at j = 19.
A study keeps per-iteration metrics, not time signals (its workers return metrics only, so that 100
seeds x 3 methods stay a few MB), so a band over seeds of e(t) itself cannot be drawn from it.
What these figures band instead is the per-iteration size of exactly the signals those figures
draw, at every iteration (the iterations the single-run figure shows are marked):

* Fig. 5 over seeds: the RMS and the peak over t of the position error |e_P(t)| and of the force
  error |e_F(t)| (``*_error_rms``, ``*_error_max``): how large the curves of Fig. 5 are, and how
  that changes from seed to seed.
* Figs. 6/7 over seeds: H, the standard deviation over t of Delta tau along X (Fig. 6) or Y
  (Fig. 7): the spread of panel (b) and of the input's deviation from the desired input in panel (a).
  In its three forms (whole grid, without t = 0, settled from t = 20 ms), because the t = 0 spike
  that Figs. 6/7 keep off scale dominates the whole-grid form.

Bands as in :mod:`ilcforce.report.study_figures` (line: median; dark band: 95% bootstrap interval of
the median; light band: central 95% of the seeds). One seed alone, the study's first (seed 0 of
``paper-mc`` is the draw the single-run report of the paper's setup shows), is drawn as a thin
dashed line without markers, so it cannot be taken for the median; if that seed diverged, a dotted
vertical line in the method's colour marks where (no marker that could read as a data point).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ilcforce.records import STATUS_DIVERGED, axis_text, task_axes
from ilcforce.report import paper, tables
from ilcforce.report.figure_style import method_color, method_text
from ilcforce.report.figures import TRACKING_ITERATIONS
from ilcforce.report.figure_files import save_figure
from ilcforce.report.study_figures import _band_plot, _bands, _log_scale, band_legend_entries
from ilcforce.stats import BOOTSTRAP_SEED, LEVEL, N_BOOTSTRAP

#: Methods Figs. 6 and 7 compare (the paper's).
INPUT_METHODS = ("c1", "c3")

CAPTION = (
    "The study keeps per-iteration metrics, not time signals, so these figures band over seeds the size of the "
    "signals Figs. 5-7 draw, at every iteration: Fig. 5's errors by their RMS and peak over t (shaded: the "
    "iterations Fig. 5 draws), Figs. 6/7's Delta tau by H, its standard deviation over t (Table 3's measure), "
    "in three forms, as the t = 0 spike dominates the whole-grid form (shaded: the iteration Figs. 6/7 draw; dash-dotted grey: the "
    "true plant's change). "
    "Line: median over seeds; dark band: 95% percentile-bootstrap interval of that median; light band: central "
    "95% of the seeds. Thin dashed line: {seed_text} alone; a dotted vertical line marks where it diverged. "
    "Seeds that diverged leave the bands from their divergence on (the legend counts the seeds at the end).")


@functools.lru_cache(maxsize=8)
def _resamples(n: int) -> np.ndarray:
    """The bootstrap indices :func:`ilcforce.stats.median_interval` draws for ``n`` values (its RNG
    is seeded per call, so they depend on ``n`` only)."""
    return np.random.default_rng(BOOTSTRAP_SEED).integers(0, n, size=(N_BOOTSTRAP, n))


def _sorted_median(rows: np.ndarray) -> np.ndarray:
    """Median along the last axis by a full sort: the same numbers as ``np.median`` (the middle
    value, or the mean (a + b) / 2 of the two middle ones), several times faster on short rows."""
    ordered = np.sort(rows, axis=-1)
    n = rows.shape[-1]
    if n % 2:
        return ordered[..., n // 2]
    return (ordered[..., n // 2 - 1] + ordered[..., n // 2]) / 2.0


def band_row(values: np.ndarray) -> tuple:
    """:func:`study_figures._bands` (median, its 95% bootstrap interval, 2.5% and 97.5% percentiles,
    n) of the finite ``values``, with the same numbers (a test pins it) at a fraction of the cost."""
    finite = values[np.isfinite(values)]
    n = finite.size
    if n < 2:
        return _bands(finite)
    boot = _sorted_median(finite[_resamples(n)])
    alpha = (1.0 - LEVEL) / 2.0
    low, high = np.quantile(boot, [alpha, 1.0 - alpha])
    lo, hi = np.percentile(finite, [2.5, 97.5])
    return float(np.median(finite)), float(low), float(high), float(lo), float(hi), int(n)


def _single_seed(frame: pd.DataFrame) -> int | None:
    return int(frame["seed"].min()) if len(frame) else None


def _draw(ax, frame: pd.DataFrame, methods, column: str, n_seeds: int, seed: int | None,
          flags: Mapping[str, str] | None, legend: bool) -> list[np.ndarray]:
    """Bands of ``column`` against j for each method, and ``seed`` alone (dashed, no markers)."""
    drawn = []
    for method in methods:
        mine = frame[frame["method"] == method]
        if mine.empty or column not in mine.columns:
            continue
        wide = mine.pivot(index="iteration", columns="seed", values=column).sort_index()
        stats = [band_row(row) for row in wide.to_numpy(dtype=float)]
        n_end = stats[-1][5] if stats else 0
        label = method_text(method) + (" (unstable learning)" if flags and method in flags else "")
        label += f", {n_end} of {n_seeds} seeds" if n_end != n_seeds else ""
        drawn.append(_band_plot(ax, wide.index.to_numpy(), stats, method, label if legend else None))
        if seed is None or seed not in wide.columns:
            continue
        one = mine[mine["seed"] == seed].set_index("iteration").sort_index()
        ok = one["status"].astype(str) != STATUS_DIVERGED
        ax.plot(one.index[ok], one.loc[ok, column], color=method_color(method), linestyle="--", linewidth=0.9,
                marker="none")
        diverged = one.index[~ok]
        if len(diverged):
            where = float(diverged[0])
            ax.axvline(where, color=method_color(method), linestyle=":", linewidth=1.5)
            ax.text(where, 0.98, f" seed {seed} diverged", transform=ax.get_xaxis_transform(), rotation=90,
                    va="top", ha="right", fontsize="x-small", color=method_color(method))
    return drawn


#: Shading of the iterations the single-run figure draws.
MARK_COLOR = "#f7efd2"


def _finish(ax, marked: tuple[int, ...], last: int, perturbation_iteration: int | None) -> None:
    for j in marked:
        if j <= last:
            ax.axvspan(j - 0.35, j + 0.35, color=MARK_COLOR, linewidth=0, zorder=0)
    if perturbation_iteration is not None and 0 < perturbation_iteration <= last:
        ax.axvline(perturbation_iteration, color="0.5", linestyle="-.", linewidth=1.0)
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def _seed_proxy(ax, seed: int | None, perturbation_iteration: int | None, perturbation_label: str = "m3 x 1.4") -> None:
    """The legend entries beyond the methods: the band shades, the seed drawn alone, the plant's change."""
    band_legend_entries(ax)
    if seed is not None:
        ax.plot([], [], color="0.3", linestyle="--", linewidth=0.9, label=f"seed {seed} alone")
    if perturbation_iteration is not None:
        ax.plot([], [], color="0.5", linestyle="-.", linewidth=1.0,
                label=f"{perturbation_label} from j = {perturbation_iteration}")


def _legend_below(fig: Figure, source, lowest) -> None:
    """One legend for the panels (``source``'s entries) at the figure's foot, and the panels' bottom margin
    set from what that legend and the ``lowest`` row's tick and axis labels measure: a fixed margin let a
    legend of many methods run over the x-axis labels and off the figure's foot (arm3-mc's Fig. 5). One
    measure on the Agg renderer (constrained layout costs a third of these figures' time)."""
    legend = fig.legend(*source.get_legend_handles_labels(), loc="lower center", bbox_to_anchor=(0.5, 0.0),
                        ncols=3, fontsize="small", title="line: median over seeds", title_fontsize="small")
    renderer = FigureCanvasAgg(fig).get_renderer()
    below = max(ax.get_window_extent(renderer).y0 - ax.get_tightbbox(renderer).y0 for ax in lowest)
    pad = 0.08 * fig.dpi  # 0.08 inch between the labels and the legend
    fig.subplots_adjust(bottom=(legend.get_window_extent(renderer).height + below + pad) / fig.bbox.height)


def figure_fig5_over_seeds(frame: pd.DataFrame, flags: Mapping[str, str] | None = None,
                           perturbation_iteration: int | None = None, perturbation_label: str = "m3 x 1.4") -> Figure:
    """Fig. 5 over seeds: RMS and peak over t of the position and force errors against j."""
    methods = tables.ordered_methods(frame["method"].unique().tolist())
    n_seeds, seed = frame["seed"].nunique(), _single_seed(frame)
    last = int(frame["iteration"].max())
    # fixed margins, not the style's constrained layout: that was a third of these figures' cost
    fig = Figure(figsize=(10.0, 7.0), layout="none")
    fig.subplots_adjust(left=0.09, right=0.98, top=0.94, hspace=0.08, wspace=0.24)  # bottom: _legend_below
    axes = fig.subplots(2, 2, sharex=True)
    panels = ((("position_error_rms", "position error |e_P|, RMS over t (m)"),
               ("position_error_max", "position error |e_P|, peak over t (m)")),
              (("force_error_rms", "force error |e_F|, RMS over t (N)"),
               ("force_error_max", "force error |e_F|, peak over t (N)")))
    for row in range(2):
        for col in range(2):
            column, ylabel = panels[row][col]
            ax = axes[row, col]
            drawn = _draw(ax, frame, methods, column, n_seeds, seed, flags, legend=(row, col) == (0, 0))
            _log_scale(ax, drawn)
            _finish(ax, TRACKING_ITERATIONS, last, perturbation_iteration)
            ax.set_ylabel(ylabel, fontsize="small")
            if row == 1:
                ax.set_xlabel("iteration j")
    _seed_proxy(axes[0, 0], seed, perturbation_iteration, perturbation_label)
    _legend_below(fig, axes[0, 0], axes[1])
    fig.suptitle(f"Fig. 5 over {n_seeds} seeds: size of the tracking errors per iteration "
                 f"(shaded: j = {', '.join(map(str, TRACKING_ITERATIONS))}, drawn in Fig. 5)", fontsize="medium")
    return fig


def figure_input_over_seeds(frame: pd.DataFrame, axis: str, flags: Mapping[str, str] | None = None,
                            perturbation_iteration: int | None = None,
                            perturbation_label: str = "m3 x 1.4") -> Figure | str:
    """Fig. 6 (``axis="x"``) or 7 (``"y"``) over seeds: H of Delta tau along ``axis`` against j, three forms.
    A 3-axis task's in-plane axes ``"u"``, ``"v"`` are Fig. 6's kind, its normal ``"n"`` Fig. 7's."""
    methods = [m for m in INPUT_METHODS if m in set(frame["method"])]
    if not methods:
        return "no C1 or C3 cells in the study"
    if f"chattering_task_{axis}" not in frame.columns:
        return f"the study's task has no axis {axis}"
    number = 7 if axis in ("y", "n") else 6  # the force axis: Fig. 7's; a position axis: Fig. 6's
    frame = frame[frame["method"].isin(methods)]
    n_seeds, seed = frame["seed"].nunique(), _single_seed(frame)
    last = int(frame["iteration"].max())
    fig = Figure(figsize=(12.0, 4.3), layout="none")
    fig.subplots_adjust(left=0.07, right=0.99, top=0.87, wspace=0.2)  # bottom: _legend_below
    axes = fig.subplots(1, 3, sharex=True)
    forms = (("", "whole grid"), ("_no_t0", "without t = 0"), ("_settled", "settled, t >= 20 ms"))
    for k, (ax, (suffix, what)) in enumerate(zip(axes, forms)):
        column = f"chattering_task_{axis}{suffix}"
        drawn = _draw(ax, frame, methods, column, n_seeds, seed, flags, legend=k == 0)
        _log_scale(ax, drawn)
        _finish(ax, (min(paper.CHATTERING_ITERATION, last),), last, perturbation_iteration)
        ax.set_title(f"H {axis_text(axis)}, {what}", fontsize="small")
        ax.set_xlabel("iteration j")
    axes[0].set_ylabel(rf"H = std over t of $\Delta\tau$ {axis_text(axis)} (N)", fontsize="small")
    _seed_proxy(axes[0], seed, perturbation_iteration, perturbation_label)
    _legend_below(fig, axes[0], axes)
    fig.suptitle(f"Fig. {number} over {n_seeds} seeds: spread of Delta tau {axis_text(axis)} per "
                 f"iteration (shaded: j = {min(paper.CHATTERING_ITERATION, last)}, drawn in Fig. {number})",
                 fontsize="medium")
    return fig


def seed_band_figures(frame: pd.DataFrame, directory: Path, tag: str, formats: tuple[str, ...],
                      flags: Mapping[str, str] | None = None,
                      perturbation_iteration: int | None = None,
                      perturbation_label: str = "m3 x 1.4") -> tuple[list[Path], list[str]]:
    """Write Figs. 5-7 over seeds for ONE setting; returns the files and the report's lines."""
    written: list[Path] = []
    notes: list[str] = []
    p = perturbation_iteration
    label = perturbation_label
    axes = task_axes(3 if "chattering_task_u" in frame.columns else 2)  # one H figure per task axis
    builders = (("fig5_tracking_error_seeds", lambda: figure_fig5_over_seeds(frame, flags, p, label)),
                *((f"fig{7 if axis in ('y', 'n') else 6}_input_{axis}_seeds",
                   lambda axis=axis: figure_input_over_seeds(frame, axis, flags, p, label)) for axis in axes))
    for stem, build in builders:
        made = build()
        if isinstance(made, str):
            notes.append(f"{stem}: not drawn ({made}).")
            continue
        written += save_figure(made, directory, f"{stem}_{tag}", formats)
    seed = _single_seed(frame)
    lines = [CAPTION.format(seed_text=f"seed {seed}" if seed is not None else "one seed"), ""]
    lines += [f"![{f.stem}]({f.name})" for f in written if f.suffix == ".png"] + notes + [""]
    return written, lines
