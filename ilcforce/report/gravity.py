"""Does C3 learn gravity? Theta_hat's G block against the plant's true task-space gravity.

With a plant that has gravity, C3's Theta carries G11 G12 (x) and G21 G22 (y) (ilcforce.controllers.c3),
multiplied by Psi's ones block, so G_i1 + G_i2 is C3's estimate of the task gravity G_i along the path.
The truth is J^-T G_q of the iteration's true plant at the desired positions
(:meth:`ilcforce.plants.base.Plant.task_gravity_along`). A learned G also absorbs whatever else is
constant along the path (the learning law cannot tell them apart), so agreement is a finding, not
a definition.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: Theta_hat's G columns in the 12-entry layout (C3Controller.theta_names with gravity)
G_COLUMNS = {"x": (4, 5), "y": (10, 11)}


def learned_gravity(theta_hat: np.ndarray) -> np.ndarray:
    """(n, 2): G_x = G11 + G12, G_y = G21 + G22 from a 12-column Theta_hat (n, 12)."""
    theta_hat = np.asarray(theta_hat, dtype=np.float64)
    if theta_hat.ndim != 2 or theta_hat.shape[1] != 12:
        raise ValueError(f"Theta_hat must have 12 columns (a plant with gravity), got shape {theta_hat.shape}")
    return np.column_stack([theta_hat[:, a] + theta_hat[:, b] for a, b in G_COLUMNS.values()])


def true_gravity(config, iteration: int, positions: np.ndarray) -> np.ndarray:
    """J^-T G_q (n, 2) of iteration ``iteration``'s true plant at ``positions`` (n, 2)."""
    from ilcforce.plants import make_plant

    return make_plant(config.plant.true_plant(iteration)).task_gravity_along(positions)


def gravity_figure(store_path: Path, config, iterations=None):
    """Figure: learned G_x, G_y (C3's Theta_hat) over time for some iterations, against the truth.

    ``store_path`` is a C3 store of a plant with gravity; ``config`` its configuration. Returns the
    matplotlib figure (one panel per task axis), built without pyplot like the report's other figures
    (:mod:`ilcforce.report.figures`), with a constrained layout (``tight_layout`` on top of the report
    style's constrained layout printed a warning for every 2R report).
    """
    from matplotlib.figure import Figure

    from ilcforce import store

    stored = store.iterations(store_path)
    if not stored:
        raise ValueError(f"{store_path}: no stored iteration")
    chosen = list(iterations) if iterations is not None else sorted({stored[0], stored[len(stored) // 2], stored[-1]})
    t = store.read_control_time(store_path)
    positions = config.reference_samples()[:, 0:2]
    fig = Figure(figsize=(9, 3.4), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True)
    metrics = store.read_metrics(store_path)
    shown: list[list[np.ndarray]] = [[], []]  # per axis: the values the y range is set from
    for j in chosen:
        g_hat = learned_gravity(store.read_memory(store_path, j)["theta_hat"])
        label = f"learned, j = {j}"
        keep = np.ones(len(t), dtype=bool)
        if j in metrics.index and str(metrics.at[j, "status"]) == "diverged":
            # the memory blows up in the last samples before the watchdog stops the iteration: say so,
            # and set the y range from before those 20 ms, so the blow-up does not flatten the rest
            when = float(metrics.at[j, "diverged_time"])
            label += f" (diverged at t = {when:.3g} s; off scale near it)"
            keep = t <= when - 0.02
        for k, ax in enumerate(axes):
            ax.plot(t, g_hat[:, k], lw=1, label=label)
            shown[k].append(g_hat[keep, k])
    truth = true_gravity(config, chosen[-1], positions)
    for k, (ax, axis) in enumerate(zip(axes, G_COLUMNS)):
        ax.plot(t, truth[:, k], "k--", lw=1.2, label=f"true J^-T G_q (j = {chosen[-1]})")
        values = np.concatenate([*shown[k], truth[:, k]])
        values = values[np.isfinite(values)]
        if values.size:
            low, high = float(values.min()), float(values.max())
            pad = 0.08 * (high - low) if high > low else max(abs(high), 1.0) * 0.1
            ax.set_ylim(low - pad, high + pad)
        i = "1" if axis == "x" else "2"
        ax.set_title(f"G_{axis}: C3's G{i}1 + G{i}2 against J^-T G_q")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("N")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=7)  # off the curves
    return fig
