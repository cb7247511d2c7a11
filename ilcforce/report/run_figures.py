"""The figures of one experiment's report: which ones, how each is built from the stores, saving.

Each builder returns a matplotlib figure, or a one-line reason it cannot be drawn (which the report
prints in the figure's place). Reads only the results store; never simulates.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

import pandas as pd
from matplotlib.figure import Figure

from ilcforce import store
from ilcforce import stability
from ilcforce.report import figures, sections, tables
from ilcforce.records import task_axes
from ilcforce.report.figure_files import ReportWriteError, save_figure

#: Figures written per experiment: file stem -> caption, the report's list of figures (what each shows).
FIGURES = {
    "fig2_reference": "Fig. 2: the reference every method tracks: desired position x_d (m) and desired contact "
                      "force F_yd (N) against time.",
    "fig3_position_error_norm": "Fig. 3: the paper's 2-norm of the position error e_P (X) at each iteration j, one "
                                "line per method, log scale. A cross above the data marks where a method "
                                "diverged (it has no value from there on); the dashed line marks the true plant's "
                                "change. Each method is drawn a little narrower than the one before it, so where two coincide the "
                                "earlier one shows as a rim. Lower is better.",
    "fig4_force_error_norm": "Fig. 4: the same for the force error e_F (Y), in N.",
    "fig5_tracking_error": "Fig. 5: the position error X (upper row, m) over the force error Y (lower row, N) "
                           "against time at j = 0, 5, 10, 15 (dark to light), one column per method (four to a row); "
                           "every panel has its own y scale, so compare sizes on the axes.",
    "fig6_input_x": "Fig. 6: C1 and C3 at j = 19 (or their last complete iteration): (a) the task-space control "
                    "input X against the desired input (dashed), (b) Delta tau = desired - applied input X, whose "
                    "standard deviation is H (Table 3). Samples before t = 20 ms may lie off scale (noted in "
                    "the panel).",
    "fig7_input_y": "Fig. 7: the same as Fig. 6 along Y.",
    "fig_alpha_hat": "C3's learned switching gain alpha_hat_j(t) (not in the paper): its profile over t at a few "
                     "iterations (top; the y range from t >= 20 ms, the spike at t = 0 named when off scale) and "
                     "its mean and maximum over t >= 20 ms at every iteration (bottom).",
    "fig_gravity": "Does C3 learn gravity? Theta_hat's G entries against the true J^-T G_q (plants with gravity "
                   "only); each panel's title gives the answer at the last iteration, as the relative RMS "
                   "error from the truth over t >= 20 ms (0% learned exactly, 100% as far off as learning "
                   "nothing).",
}


def task_roles(config: Mapping) -> tuple[tuple[str, ...], str]:
    """(the position axes, the force axis) of a stored configuration's task (:func:`ilcforce.records.task_axes`
    named by the selection S): (x,), y on the planar task; (u, v), n on a plane."""
    selection = list((config.get("surface") or {}).get("selection") or (0.0, 1.0))
    axes = task_axes(len(selection))
    force = [a for a, s in zip(axes, selection) if s]
    return tuple(a for a, s in zip(axes, selection) if not s), (force[0] if force else axes[-1])


def figure_captions(config: Mapping) -> dict[str, str]:
    """:data:`FIGURES` for the stored configuration's task: the planar captions, or on another task the same
    figures along its axes (Figs. 6 and 7 once per position axis and for the force axis)."""
    position, force = task_roles(config)
    if position == ("x",) and force == "y":
        return dict(FIGURES)
    names = " and ".join(f"{a}_d" for a in position)
    along = "the " + " and ".join(position) + (" axes" if len(position) > 1 else " axis")
    changed = {
        "fig2_reference": f"Fig. 2: the reference every method tracks: desired position {names} (m) and desired "
                          f"contact force F_{force}d (N) along the {force} axis against time.",
        "fig3_position_error_norm": FIGURES["fig3_position_error_norm"].replace("e_P (X)", f"e_P (along {along})"),
        "fig4_force_error_norm": FIGURES["fig4_force_error_norm"].replace("e_F (Y)", f"e_F (along the {force} axis)"),
        "fig5_tracking_error": f"Fig. 5: the position errors along {along} (upper rows, m) over the force error along "
                               f"the {force} axis (lowest row, N) against time at j = 0, 5, 10, 15 (dark to light), "
                               "one column per method (four to a row); every panel has its own y scale, so compare "
                               "sizes on the axes.",
    }
    captions = {}
    for stem, caption in FIGURES.items():
        if stem == "fig6_input_x":
            captions.update({f"fig6_input_{a}": caption.replace("input X", f"input along {a}") for a in position})
        elif stem == "fig7_input_y":
            captions[f"fig7_input_{force}"] = f"Fig. 7: the same as Fig. 6 along {force}."
        else:
            captions[stem] = changed.get(stem, caption)
    return captions


#: Every figure format the report can write; by default it writes PNG only (the pages link the
#: PNG; a PDF of each figure doubles the drawing time of a full report), PDF on request (--pdf).
FIGURE_FORMATS = ("png", "pdf")
DEFAULT_FORMATS = ("png",)

#: Errors a store reader may raise for a bad file (StoreError) or unexpected contents.
READ_ERRORS = (store.StoreError, OSError, KeyError, ValueError, TypeError)


def _figure_builders(experiment, p: int,
                     flags: Mapping[str, str]) -> dict[str, Callable[[], Figure | str]]:
    """Stem -> a callable making the figure, or returning a one-line reason it cannot be drawn."""
    methods = experiment.methods
    labels = {m: figures.method_label(m) + "".join(
        f" [{d.split(',')[0]}]" for d in sections.law_differences(m, experiment.config(m)))
        + (f" ({stability.UNSTABLE})" if m in flags else "") for m in methods}

    position_axes, force_axis = task_roles(experiment.config())

    def reference() -> Figure | str:
        first = next(iter(methods.values()))
        return figures.figure_reference(store.read_reference(first.path), position_axes, force_axis)

    def norms(column: str, ylabel: str) -> Callable[[], Figure | str]:
        return lambda: figures.figure_error_norm(experiment.metrics, column, ylabel, perturbation_iteration=p,
                                                 perturbation_label=sections.perturbation_label(experiment.config()),
                                                 labels=labels)

    def tracking() -> Figure | str:
        frames: dict[str, dict[int, pd.DataFrame]] = {}
        for name, method in methods.items():
            stored = {int(j) for j in method.metrics.index}  # every committed iteration, diverged included
            frames[name] = {
                j: store.read_iteration(method.path, j) for j in figures.TRACKING_ITERATIONS if j in stored
            }
        return figures.figure_tracking_error(frames, labels=labels,
                                             rows=figures.tracking_rows(position_axes, force_axis))

    def inputs(axis: str) -> Callable[[], Figure | str]:
        def build() -> Figure | str:
            chosen, read_at, absent = {}, {}, {}
            for name in ("c1", "c3"):
                if name not in methods:
                    continue
                j = tables.chattering_iteration(methods[name].metrics)
                if j is not None:
                    chosen[name] = store.read_iteration(methods[name].path, j)
                    read_at[name] = j
                else:  # say why a method is missing rather than leave the reader to guess
                    statuses = methods[name].metrics["status"].astype(str)
                    diverged = methods[name].metrics.index[statuses != "complete"]
                    absent[name] = ("no complete iteration" + (f" (diverged at j = {int(diverged[0])})"
                                                               if len(diverged) else ""))
            if not chosen:
                return "no complete C1 or C3 iteration"
            return figures.figure_input(chosen, axis, iterations=read_at, labels=labels, absent=absent)

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
        return figures.figure_switching_gain(alphas, duration, profiles=profiles, unit=unit, perturbation_iteration=p,
                                             perturbation_label=sections.perturbation_label(experiment.config()))

    def gravity() -> Figure | str:
        if "c3" not in methods:
            return "no C3 results"
        from ilcforce.report.gravity import gravity_figure
        from ilcforce.store.run import open_run

        path = methods["c3"].path
        first = tables.complete_iterations(methods["c3"].metrics) or [int(j) for j in methods["c3"].metrics.index]
        from ilcforce.report.gravity import task_dimension

        try:
            task_dimension(store.read_memory(path, first[0])["theta_hat"]) if first else None
        except ValueError:
            first = []
        if not first:
            return "the plant has no gravity: C3's Theta has no G entries"
        return gravity_figure(path, open_run(path).config)

    return {
        "fig2_reference": reference,
        "fig3_position_error_norm": norms("position_error_2norm", "position error 2-norm (m)"),
        "fig4_force_error_norm": norms("force_error_2norm", "force error 2-norm (N)"),
        "fig5_tracking_error": tracking,
        **{f"fig6_input_{axis}": inputs(axis) for axis in position_axes},
        f"fig7_input_{force_axis}": inputs(force_axis),
        "fig_alpha_hat": alpha_hat,
        "fig_gravity": gravity,
    }


def write_figures(experiment, directory: Path, p: int, formats: tuple[str, ...],
                   flags: Mapping[str, str]) -> list[Path]:
    written: list[Path] = []
    if not experiment.methods or not formats:
        for stem in figure_captions(experiment.config()):
            experiment.notes[stem] = "no readable store" if not experiment.methods else "no figure format requested"
        return written
    for stem, build in _figure_builders(experiment, p, flags).items():
        try:
            with figures.report_style():
                made = build()
                if isinstance(made, str):
                    experiment.notes[stem] = made
                    continue
                written += save_figure(made, directory, stem, formats)
        except ReportWriteError:
            raise
        except READ_ERRORS as error:
            experiment.notes[stem] = f"not drawn: {' '.join(str(error).split())}"
            experiment.warn(f"{stem} not drawn: {error}")
    return written

