"""The report's figures (the paper's Figs. 2-7 and the learned switching gain).

Every ``plot_*`` function draws on the Axes it is given and returns the artists it drew; none
creates a figure, shows or saves one. The ``figure_*`` functions compose those into a
:class:`matplotlib.figure.Figure` built directly (no pyplot, so no GUI backend and no global
figure registry); :mod:`ilcforce.report.build` saves them. Wrap figure creation and saving in
``with report_style():`` so that the single style file applies.

Inputs are the DataFrames the store readers return: metrics frames indexed by iteration j,
iteration frames and the reference indexed by time t (s) with columns ``<signal>_<axis>``.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from ilcforce.records import STATUS_COMPLETE, axis_text
from ilcforce.report import paper
from ilcforce.report.figure_style import (HEADROOM, HEADROOM_BASE, HEADROOM_PER_ROW, RANGE_FROM, free_top,  # noqa: F401
                                          method_color, method_label, method_text, range_without_start,
                                          report_style)

#: Fig. 5 shows these iterations (Section 4.2.1).
TRACKING_ITERATIONS = (0, 5, 10, 15)


def _time(frame: pd.DataFrame) -> np.ndarray:
    return np.asarray(frame.index.to_numpy(), dtype=float)


# ---------------------------------------------------------------------------------------------
# Plot functions: draw on the given axes, return the artists
# ---------------------------------------------------------------------------------------------


def plot_desired_position(ax: Axes, reference: pd.DataFrame, axes: Sequence[str] = ("x",)) -> list[Artist]:
    """Fig. 2 (a): desired position x_d (m) against time (s), one line per position axis (u_d, v_d on a plane)."""
    artists: list[Artist] = []
    styles = ("-", "--", ":")
    for k, axis in enumerate(axes):
        artists += ax.plot(_time(reference), reference[f"position_desired_{axis}"], color="k",
                           linestyle=styles[k % len(styles)], label=f"${axis}_d$")
    ax.set_xlabel("time (s)")
    names = ", ".join(f"${axis}_d$" for axis in axes)
    ax.set_ylabel(f"desired position {names} (m)")
    if len(axes) > 1:
        ax.legend()
    return artists


def plot_desired_force(ax: Axes, reference: pd.DataFrame, axis: str = "y") -> list[Artist]:
    """Fig. 2 (b): desired contact force F_yd (N) against time (s), along the force axis ``axis``."""
    artists: list[Artist] = list(ax.plot(_time(reference), reference[f"force_desired_{axis}"], color="k",
                                         label=f"$F_{{{axis}d}}$"))
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"desired force $F_{{{axis}d}}$ (N)")
    return artists


#: Marker of the iteration at which a method diverged (Figs. 3, 4): drawn at the top of the axes,
#: stacked when several methods diverged at the same iteration, never at a data value.
DIVERGED_MARKER = "X"


def plot_error_norms(
    ax: Axes,
    metrics_by_method: Mapping[str, pd.DataFrame],
    column: str,
    *,
    perturbation_iteration: int | None = paper.PERTURBATION_ITERATION,
    perturbation_label: str = "m3 x 1.4",
    ylabel: str = "",
    labels: Mapping[str, str] | None = None,
) -> list[Artist]:
    """Figs. 3, 4: ``metrics[column]`` (an error 2-norm) against iteration j for every method, log y.

    Only complete iterations are drawn. A method that diverged says so in its legend label
    ("diverged at j = 3") and gets a cross in its colour at that iteration along the top edge of the
    axes (outside the data, so it cannot read as a value); crosses of methods that diverged at the
    same iteration are stacked, one under the other, so none hides another (a method that diverged
    at j = 0 has no point, and the cross is what shows it). A grey dashed line marks
    ``perturbation_iteration`` (None: none), labelled ``perturbation_label`` (the configuration's
    change, e.g. "m2 x 1.4"). The legend stands outside the axes, on the right, off the data. Each
    method is drawn a little narrower than the one before it, so one lying on another (C1 and SMC-BL
    after the 2R arm's change) leaves the other's rim visible.
    """
    artists: list[Artist] = []
    stacked: dict[float, int] = {}
    for k, (method, metrics) in enumerate(metrics_by_method.items()):
        complete = metrics["status"].astype(str).to_numpy() == STATUS_COMPLETE
        j = np.asarray(metrics.index.to_numpy()[complete], dtype=float)
        values = np.asarray(metrics[column].to_numpy()[complete], dtype=float)
        label = method_text(method, labels)
        diverged = metrics.index[metrics["status"].astype(str).to_numpy() != STATUS_COMPLETE]
        if len(diverged):
            label += f", diverged at j = {int(diverged[0])}"
        (line,) = ax.plot(j, values, marker="o", color=method_color(method), label=label, zorder=2 + 0.01 * k,
                          markersize=max(3.0, 8.0 - 0.7 * k), linewidth=max(0.9, 2.8 - 0.3 * k))
        artists.append(line)
        if len(diverged):
            where = float(diverged[0])
            level = stacked.get(where, 0)
            stacked[where] = level + 1
            artists += ax.plot([where], [0.97 - 0.06 * level], transform=ax.get_xaxis_transform(), linestyle="none",
                               marker=DIVERGED_MARKER, markersize=8, color=line.get_color(), clip_on=False)
    if any(np.any(np.asarray(line.get_ydata(), dtype=float) > 0) for line in artists if hasattr(line, "get_marker")
           and line.get_marker() == "o"):
        ax.set_yscale("log")
    if stacked:  # room above the data for the crosses, and one legend entry that says what they are
        free_top(ax, 0.06 * max(stacked.values()) + 0.04)
        ax.plot([], [], linestyle="none", marker=DIVERGED_MARKER, markersize=8, color="0.35",
                label="diverged at this j (no value from there on)")
    if perturbation_iteration is not None:
        artists.append(ax.axvline(perturbation_iteration, color="0.4", linestyle="--", linewidth=1.0,
                                  label=f"{perturbation_label} from j = {perturbation_iteration}"))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration j")
    ax.set_ylabel(ylabel or column)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    return artists


def iteration_colour(j: int):
    """A colour of its own for each of Fig. 5's iterations (TRACKING_ITERATIONS), from a sequential map
    (dark early, light late): the method colours (C0, C1, ...) stay the methods'."""
    from matplotlib import colormaps

    if j not in TRACKING_ITERATIONS:
        return "0.5"
    shades = colormaps["viridis"](np.linspace(0.0, 0.8, len(TRACKING_ITERATIONS)))
    return shades[TRACKING_ITERATIONS.index(j)]


#: Characters per line of a panel's title in Fig. 5 (a method's label, wrapped)
TITLE_WIDTH = 30
#: Methods side by side in Fig. 5 before it wraps to another pair of rows (seven in one row made
#: the figure 4,200 px wide).
TRACKING_COLUMNS = 4


def plot_tracking_error(
    ax: Axes,
    frames_by_iteration: Mapping[int, pd.DataFrame],
    column: str,
    *,
    ylabel: str | None = None,
    title: str = "",
    legend: bool = True,
) -> list[Artist]:
    """Fig. 5: one error signal (e.g. ``position_error_x``) against time, one line per iteration.

    ``ylabel``: None labels the axis with ``column``; "" leaves it unlabelled. ``legend``: False
    when the figure holds one legend for all its panels."""
    artists: list[Artist] = []
    for j, frame in sorted(frames_by_iteration.items()):
        artists += ax.plot(_time(frame), frame[column], color=iteration_colour(j), label=f"j = {j}")
    # one number format on every panel: a multiplier (x1e-4) where the values are small, never an offset
    ax.ticklabel_format(axis="y", style="sci", scilimits=(-2, 3), useOffset=False)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(column if ylabel is None else ylabel)
    if title:  # wrapped: a method's label with its law differences ran into its neighbour's
        ax.set_title("\n".join(textwrap.wrap(title, TITLE_WIDTH)), fontsize="medium")
    if artists and legend:
        ax.legend()
    return artists


def _input_label(method: str, iterations: Mapping[str, int] | None, labels: Mapping[str, str] | None = None) -> str:
    if iterations is None or method not in iterations:
        return method_text(method, labels)
    return f"{method_text(method, labels)}, j = {iterations[method]}"


def plot_task_input(
    ax: Axes, frames_by_method: Mapping[str, pd.DataFrame], axis: str, *, iterations: Mapping[str, int] | None = None,
    labels: Mapping[str, str] | None = None,
) -> list[Artist]:
    """Figs. 6 (a), 7 (a): task-space input F_E along ``axis`` ("x", "y"; "u", "v", "n") against time, per method.

    The desired input J^-T tau_d of the first frame is drawn dashed for reference. ``iterations``
    (method -> j), if given, labels each line with the iteration it shows.
    """
    artists: list[Artist] = []
    for method, frame in frames_by_method.items():
        artists += ax.plot(
            _time(frame), frame[f"task_input_{axis}"], color=method_color(method),
            label=_input_label(method, iterations, labels)
        )
    for frame in list(frames_by_method.values())[:1]:
        artists += ax.plot(
            _time(frame), frame[f"desired_task_input_{axis}"], color="k", linestyle="--", linewidth=0.8, label="desired"
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel(f"control input {axis_text(axis)} (N)")
    if artists:
        ax.legend()
    return artists


def plot_input_deviation(
    ax: Axes, frames_by_method: Mapping[str, pd.DataFrame], axis: str, *, iterations: Mapping[str, int] | None = None,
    labels: Mapping[str, str] | None = None,
) -> list[Artist]:
    """Figs. 6 (b), 7 (b): Delta = desired_task_input - task_input along ``axis`` against time."""
    artists: list[Artist] = []
    for method, frame in frames_by_method.items():
        delta = frame[f"desired_task_input_{axis}"] - frame[f"task_input_{axis}"]
        artists += ax.plot(
            _time(frame), delta, color=method_color(method), label=_input_label(method, iterations, labels), linewidth=0.8
        )
    ax.set_xlabel("time (s)")
    ax.set_ylabel(rf"$\Delta\tau$ {axis_text(axis)} (N)")
    if artists:
        ax.legend()
    return artists


def control_time(n_control: int, duration: float) -> np.ndarray:
    """Control grid t_k = k T / (n_control - 1), k = 0 .. n_control - 1, in s."""
    return np.linspace(0.0, duration, n_control)


def plot_switching_gain(
    ax: Axes, alpha_by_iteration: Mapping[int, np.ndarray], duration: float, *, unit: str = "N"
) -> list[Artist]:
    """C3's learned switching gain alpha_hat_j(t) against time, one line per iteration j.

    ``alpha_by_iteration[j]`` has shape (n_control,): the memory after iteration j, on the control
    grid spanning [0, duration] s.
    """
    artists: list[Artist] = []
    series = []
    for j, alpha in sorted(alpha_by_iteration.items()):
        alpha = np.asarray(alpha, dtype=float).reshape(-1)
        t = control_time(alpha.size, duration)
        artists += ax.plot(t, alpha, label=f"j = {j}")
        series.append((t, alpha))
    ax.set_xlabel("time (s)")
    ax.set_ylabel(rf"learned switching gain $\hat\alpha_j$ ({unit})")
    # the y range from t >= RANGE_FROM: the spike at t = 0 (the start mismatch) no longer flattens
    # the settled alpha_hat, the value the findings quote; it is named in the legend
    note = range_without_start(ax, series, headroom=0.35) if series else ""
    if artists:
        handles, texts = ax.get_legend_handles_labels()
        if note:
            from matplotlib.lines import Line2D

            handles, texts = [*handles, Line2D([], [], linestyle="none")], [*texts, note.replace("\n", " ")]
        ax.legend(handles, texts, ncols=3, fontsize="x-small", loc="upper left")
    return artists


def plot_switching_gain_mean(
    ax: Axes, alpha_by_iteration: Mapping[int, np.ndarray], *, unit: str = "N", duration: float | None = None,
    perturbation_iteration: int | None = None, perturbation_label: str = "m3 x 1.4",
) -> list[Artist]:
    """Mean over time and maximum over time of alpha_hat_j against iteration j; with ``duration``
    (the control grid's span, s), over t >= RANGE_FROM (settled: the t = 0 spike would be the maximum)."""
    js = sorted(alpha_by_iteration)

    def settled(alpha) -> np.ndarray:
        alpha = np.asarray(alpha, dtype=float).reshape(-1)
        return alpha if duration is None else alpha[control_time(alpha.size, duration) >= RANGE_FROM]

    mean = [float(np.mean(settled(alpha_by_iteration[j]))) for j in js]
    peak = [float(np.max(settled(alpha_by_iteration[j]))) for j in js]
    over = "over t" if duration is None else f"over t >= {RANGE_FROM * 1e3:.0f} ms"
    artists: list[Artist] = []
    artists += ax.plot(js, mean, marker="o", color=method_color("c3"), label=f"mean {over}")
    artists += ax.plot(js, peak, marker="s", color=method_color("c3"), linestyle=":", label=f"max {over}")
    if perturbation_iteration is not None and js and js[0] <= perturbation_iteration <= js[-1]:
        artists.append(ax.axvline(perturbation_iteration, color="0.4", linestyle="--", linewidth=1.0,
                                  label=f"{perturbation_label} from j = {perturbation_iteration}"))
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("iteration j")
    ax.set_ylabel(rf"$\hat\alpha_j$ ({unit})")
    ax.legend()
    return artists


# ---------------------------------------------------------------------------------------------
# Figure composers (no saving)
# ---------------------------------------------------------------------------------------------


def figure_reference(reference: pd.DataFrame, position_axes: Sequence[str] = ("x",), force_axis: str = "y") -> Figure:
    """Fig. 2: desired position (each position axis) and desired force (the force axis)."""
    fig = Figure(figsize=(6.4, 4.4))
    ax_position, ax_force = fig.subplots(2, 1, sharex=True)
    plot_desired_position(ax_position, reference, position_axes)
    plot_desired_force(ax_force, reference, force_axis)
    ax_position.set_xlabel("")
    return fig


def figure_error_norm(
    metrics_by_method: Mapping[str, pd.DataFrame],
    column: str,
    ylabel: str,
    *,
    perturbation_iteration: int | None,
    perturbation_label: str = "m3 x 1.4",
    labels: Mapping[str, str] | None = None,
) -> Figure:
    """Figs. 3, 4: one error 2-norm against iteration for every method (legend on the right)."""
    fig = Figure(figsize=(9.0, 4.2), layout="constrained")
    ax = fig.subplots()
    plot_error_norms(ax, metrics_by_method, column, perturbation_iteration=perturbation_iteration,
                     perturbation_label=perturbation_label, ylabel=ylabel, labels=labels)
    return fig


#: Fig. 5's rows on the planar task: (logged column, axis label)
TRACKING_ROWS = (("position_error_x", "position error X (m)"), ("force_error_y", "force error Y (N)"))


def tracking_rows(position_axes: Sequence[str], force_axis: str) -> tuple[tuple[str, str], ...]:
    """Fig. 5's rows for a task: each position axis's error, then the force axis's (``TRACKING_ROWS`` on x, y)."""
    return (*((f"position_error_{a}", f"position error {axis_text(a)} (m)") for a in position_axes),
            (f"force_error_{force_axis}", f"force error {axis_text(force_axis)} (N)"))


def figure_tracking_error(frames: Mapping[str, Mapping[int, pd.DataFrame]], *,
                          labels: Mapping[str, str] | None = None,
                          rows: Sequence[tuple[str, str]] = TRACKING_ROWS) -> Figure:
    """Fig. 5: the position error X (top row) over the force error Y (bottom row), one column per method;
    ``rows`` (column, label) for another task (on a plane: position errors U and V, then force error N).

    ``frames[method][j]`` is the iteration frame of iteration j (j in 0, 5, 10, 15 where run).
    Every panel has its own y scale, as the paper's had: one shared scale let a method with a 100x
    larger error flatten the others (C1, C2 and C3, the paper's comparison) to lines at zero. Read
    the sizes on each panel's axis. One legend for the iterations, below the panels.
    """
    methods = list(frames)
    n = max(1, len(methods))
    per = len(rows)
    columns = min(n, TRACKING_COLUMNS)
    blocks = -(-n // columns)  # each block: one row of panels per signal
    fig = Figure(figsize=(2.4 * columns + 0.4, 2.0 * per * blocks + 0.7), layout="constrained")
    axes = np.atleast_2d(fig.subplots(per * blocks, columns, sharex=True, squeeze=False))
    for k, method in enumerate(methods):
        block, column = divmod(k, columns)
        panels = [axes[per * block + r, column] for r in range(per)]
        for r, (ax, (signal, label)) in enumerate(zip(panels, rows)):
            plot_tracking_error(ax, frames[method], signal, ylabel=label if column == 0 else "",
                                title=method_text(method, labels) if r == 0 else "", legend=False)
            if r < per - 1:
                ax.set_xlabel("")
        if k + columns < n:  # another method below in this column: its time axis serves both
            panels[-1].set_xlabel("")
        else:  # the lowest panel of its column: its time ticks shown (sharex hid them above the last row)
            panels[-1].xaxis.set_tick_params(labelbottom=True)
    for k in range(n, blocks * columns):  # the empty places of the last block
        block, column = divmod(k, columns)
        for r in range(per):
            axes[per * block + r, column].set_visible(False)
    handles = {}
    for ax in axes.ravel():
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="outside lower center", ncols=len(handles),
                   title="iteration (each panel on its own y scale)")
    return fig


def figure_input(
    frames_by_method: Mapping[str, pd.DataFrame], axis: str, *, iterations: Mapping[str, int] | None = None,
    labels: Mapping[str, str] | None = None, absent: Mapping[str, str] | None = None,
) -> Figure:
    """Figs. 6 (``axis="x"``; on a plane "u", "v"), 7 (``"y"``; "n"): (a) control input, (b) Delta tau, C1 and
    C3 at j = 19.

    One row per method (they no longer hide each other), (a) and (b) side by side, each panel on
    its own scale (C1's Delta tau is about ten times C3's; compare the values, and H in Table 3).
    The y range is set from
    t >= RANGE_FROM, so the start mismatch at t = 0 does not flatten the rest; what lies off
    scale is written in the panel, in a free band above the data that it shares with the legend, at the
    band's right end (the start's spike runs up through its left end).
    ``absent`` (method -> reason) names a method that has no row, in the figure's title.
    """
    methods = list(frames_by_method)
    n = max(1, len(methods))
    fig = Figure(figsize=(9.0, 2.6 * n + 0.6), layout="constrained")
    axes = np.atleast_2d(fig.subplots(n, 2, sharex=True, squeeze=False))
    for k, method in enumerate(methods):
        one = {method: frames_by_method[method]}
        named = {method: method_text(method, labels)}
        ax_input, ax_delta = axes[k]
        plot_task_input(ax_input, one, axis, iterations=iterations, labels=named)
        plot_input_deviation(ax_delta, one, axis, iterations=iterations, labels=named)
        frame = frames_by_method[method]
        t = _time(frame)
        for ax, series in (
            (ax_input, [(t, frame[f"task_input_{axis}"]), (t, frame[f"desired_task_input_{axis}"])]),
            (ax_delta, [(t, frame[f"desired_task_input_{axis}"] - frame[f"task_input_{axis}"])]),
        ):
            # the data fill the lower part; the legend, the note its last line, stands in the band above,
            # which is as tall as the legend's rows, at its RIGHT end: the only samples that reach into the
            # band are the start mismatch's before t = RANGE_FROM (off scale), at the left edge
            note = range_without_start(ax, series)
            handles, texts = ax.get_legend_handles_labels()
            if note:  # one more line of the legend: a long method label can never cover it
                from matplotlib.lines import Line2D

                handles, texts = [*handles, Line2D([], [], linestyle="none")], [*texts, note.replace("\n", " ")]
            columns = 2 if not note else 1
            rows = -(-len(texts) // columns)
            range_without_start(ax, series, headroom=HEADROOM_BASE + HEADROOM_PER_ROW * rows)
            ax.legend(handles, texts, loc="upper right", ncols=columns, fontsize="x-small")
        if k < n - 1:
            ax_input.set_xlabel("")
            ax_delta.set_xlabel("")
    axes[0, 0].set_title(f"(a) control input, {axis_text(axis)}")
    axes[0, 1].set_title(rf"(b) $\Delta\tau$, {axis_text(axis)}")
    if absent:  # ``absent``: method -> why it has no row here
        fig.suptitle("; ".join(f"{method_text(m, labels)} not drawn: {why}" for m, why in absent.items()),
                     fontsize="small")
    return fig


def figure_switching_gain(
    alpha_by_iteration: Mapping[int, np.ndarray], duration: float, *, profiles: Sequence[int] = (), unit: str = "N",
    perturbation_iteration: int | None = None, perturbation_label: str = "m3 x 1.4",
) -> Figure:
    """alpha_hat_j(t) for the iterations in ``profiles`` (all if empty), and its mean/max per j."""
    fig = Figure(figsize=(6.4, 5.0), layout="constrained")
    ax_profiles, ax_mean = fig.subplots(2, 1)
    chosen = {j: a for j, a in alpha_by_iteration.items() if not profiles or j in profiles}
    plot_switching_gain(ax_profiles, chosen, duration, unit=unit)
    plot_switching_gain_mean(ax_mean, alpha_by_iteration, unit=unit, duration=duration,
                             perturbation_iteration=perturbation_iteration, perturbation_label=perturbation_label)
    return fig


def profile_iterations(iterations: Sequence[int], count: int = 5) -> list[int]:
    """About ``count`` iterations spread evenly over ``iterations`` (first and last included)."""
    iterations = sorted(iterations)
    if len(iterations) <= count:
        return iterations
    picks = np.linspace(0, len(iterations) - 1, count)
    return sorted({iterations[int(math.floor(p + 0.5))] for p in picks})
