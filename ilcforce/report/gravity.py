"""Does C3 learn gravity? Theta_hat's G block against the plant's true task-space gravity.

With a plant that has gravity, C3's Theta carries a G row per task axis, G11 G12 (x) and G21 G22 (y) on the
planar task, G_i1 .. G_in on n axes (ilcforce.controllers.c3), multiplied by Psi's ones block, so the row's sum
is C3's estimate of the task gravity G_i along the path. The truth is J_X^-T G_q of the iteration's true plant
at the desired positions (``task_gravity_along`` of the plant, in the task frame). A learned G also absorbs whatever else is
constant along the path (the learning law cannot tell them apart), so agreement is a finding, not
a definition.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ilcforce.records import task_axes

#: Line style and width per drawn iteration, first to last: an earlier iteration is drawn wider
#: underneath, so a later one that lies on it leaves it visible (j = 10 was hidden under j = 19).
ITERATION_STYLES = (("-", 2.6), ("--", 1.8), ("-", 0.6), ("-.", 0.6))


def gravity_error(learned: np.ndarray, truth: np.ndarray) -> float:
    """RMS of learned - truth relative to the truth's RMS (1-D arrays of one axis, same samples):
    0 is the truth learned exactly, 1 is as far off as learning nothing."""
    truth_rms = float(np.sqrt(np.mean(np.square(truth))))
    if not truth_rms > 0:
        return float("nan")
    return float(np.sqrt(np.mean(np.square(learned - truth)))) / truth_rms


def task_dimension(theta_hat: np.ndarray) -> int:
    """n of a Theta_hat with gravity (3 n^2 columns: per axis its D, C and G rows); ValueError otherwise."""
    columns = np.shape(theta_hat)[-1] if np.ndim(theta_hat) == 2 else 0
    n = int(round(math.sqrt(columns / 3))) if columns else 0
    if n < 1 or 3 * n * n != columns:
        raise ValueError(f"Theta_hat must have 3 n^2 columns (a plant with gravity), got shape {np.shape(theta_hat)}")
    return n


def learned_gravity(theta_hat: np.ndarray) -> np.ndarray:
    """(samples, n): G_i = the sum of axis i's G row (G_x = G11 + G12, G_y = G21 + G22 on the planar task) from
    a Theta_hat with gravity (samples, 3 n^2)."""
    theta_hat = np.asarray(theta_hat, dtype=np.float64)
    n = task_dimension(theta_hat)
    return np.column_stack([theta_hat[:, 3 * n * i + 2 * n:3 * n * (i + 1)].sum(axis=1) for i in range(n)])


def true_gravity(config, iteration: int, positions: np.ndarray) -> np.ndarray:
    """J_X^-T G_q (samples, n) in the task frame of iteration ``iteration``'s true plant at the task-frame
    ``positions`` (samples, n); the task frame is R = I on the planar task."""
    from ilcforce.plants import make_plant

    robot = make_plant(config.plant.true_plant(iteration))
    n = positions.shape[1]
    frame = config.wall.frame(n)  # X = R P, so a row P = X R, and G in the task frame R G_world
    return robot.task_gravity_along(positions @ frame) @ frame.T


def gravity_figure(store_path: Path, config, iterations=None):
    """Figure: learned G per task axis (C3's Theta_hat; G_x, G_y on the planar task) over time for some
    iterations, against the truth.

    Each panel's title answers the figure's question for the last iteration drawn: how far the
    learned G is from the truth (relative RMS over t >= 20 ms, :func:`gravity_error`). The y range
    is set from t >= 20 ms (the start mismatch at t = 0 makes the memory spike there; the spike is
    named in the legend when it lies off scale).

    ``store_path`` is a C3 store of a plant with gravity; ``config`` its configuration. Returns the
    matplotlib figure (one panel per task axis), built without pyplot like the report's other figures
    (:mod:`ilcforce.report.figures`), with a constrained layout (``tight_layout`` on top of the report
    style's constrained layout printed a warning for every 2R report).
    """
    from matplotlib.figure import Figure

    from ilcforce import store
    from ilcforce.report.figures import RANGE_FROM

    stored = store.iterations(store_path)
    if not stored:
        raise ValueError(f"{store_path}: no stored iteration")
    chosen = list(iterations) if iterations is not None else sorted({stored[0], stored[len(stored) // 2], stored[-1]})
    t = store.read_control_time(store_path)
    dim = config.dimension
    positions = config.reference_samples()[:, 0:dim]
    fig = Figure(figsize=(4.5 * dim, 3.4), layout="constrained")
    axes = fig.subplots(1, dim, sharex=True)
    metrics = store.read_metrics(store_path)
    shown: list[list[np.ndarray]] = [[] for _ in range(dim)]  # per axis: the values the y range is set from
    start_peak = [0.0] * dim  # per axis: the largest |value| before RANGE_FROM, drawn off scale
    settled = t >= RANGE_FROM
    learned_last = None
    for n, j in enumerate(chosen):
        g_hat = learned_gravity(store.read_memory(store_path, j)["theta_hat"])
        label = f"learned, j = {j}"
        keep = settled.copy()
        if j in metrics.index and str(metrics.at[j, "status"]) == "diverged":
            # the memory blows up in the last samples before the watchdog stops the iteration: say so,
            # and set the y range from before those 20 ms, so the blow-up does not flatten the rest
            when = float(metrics.at[j, "diverged_time"])
            label += f" (diverged at t = {when:.3g} s; off scale near it)"
            keep &= t <= when - 0.02
        style, width = ITERATION_STYLES[min(n, len(ITERATION_STYLES) - 1)]
        for k, ax in enumerate(axes):
            ax.plot(t, g_hat[:, k], lw=width, linestyle=style, color=f"C{n}", label=label, zorder=2 + n,
                    alpha=0.85 if n else 1.0)
            shown[k].append(g_hat[keep, k])
            early = g_hat[~settled, k]
            if early.size:
                start_peak[k] = max(start_peak[k], float(np.nanmax(np.abs(early))))
        learned_last = g_hat
    truth = true_gravity(config, chosen[-1], positions)
    for k, (ax, axis) in enumerate(zip(axes, task_axes(dim))):
        ax.plot(t, truth[:, k], "k", lw=1.0, label=f"true J^-T G_q (j = {chosen[-1]})", zorder=10)
        values = np.concatenate([*shown[k], truth[settled, k]])
        values = values[np.isfinite(values)]
        if values.size:
            low, high = float(values.min()), float(values.max())
            pad = 0.08 * (high - low) if high > low else max(abs(high), 1.0) * 0.1
            ax.set_ylim(low - pad, high + pad)
            if start_peak[k] > max(abs(low), abs(high)) + pad:
                ax.plot([], [], linestyle="none", label=f"off scale before t = {RANGE_FROM * 1e3:.0f} ms: "
                        f"|G_{axis}| up to {start_peak[k]:.3g} N")
        row = " + ".join(f"G{k + 1}{c + 1}" for c in range(dim))
        off = gravity_error(learned_last[settled, k], truth[settled, k])
        ax.set_title(f"G_{axis} = C3's {row}: at j = {chosen[-1]}, {off:.0%} off J^-T G_q\n"
                     f"(relative RMS error, t >= {RANGE_FROM * 1e3:.0f} ms)", fontsize="medium")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("N")
    handles, texts = axes[0].get_legend_handles_labels()  # the curves, then each panel's off-scale note
    for ax in axes[1:]:
        more = [(h, x) for h, x in zip(*ax.get_legend_handles_labels()) if x.startswith("off scale")]
        handles, texts = [*handles, *(h for h, _ in more)], [*texts, *(x for _, x in more)]
    fig.legend(handles, texts, loc="outside lower center", ncols=3, fontsize=7)  # off the curves
    return fig
