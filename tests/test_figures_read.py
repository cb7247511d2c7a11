"""Figures read right, checked on figures drawn from small real stores: no y range set by the
samples at t = 0 alone (the start mismatch spikes there), a marker at the plant's change on every
iteration axis, every iteration or method asked for drawn, and at most 2,000 px a side as saved."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ilcforce import store
from ilcforce.experiment import run_method
from ilcforce.report import figures, tables
from ilcforce.report.figures import RANGE_FROM
from ilcforce.report.gravity import gravity_figure
from ilcforce.store.run import open_run

#: The report saves at savefig.dpi of its style (style.mplstyle), read from the file itself.
SAVE_DPI = float(re.search(r"^savefig\.dpi\s*:\s*([0-9.]+)", (Path(figures.__file__).parent / "style.mplstyle")
                           .read_text(encoding="utf-8"), re.M).group(1))
MAX_SIDE_PX = 2000
P = 2  # the plant's change in the small runs


def assert_small_enough(fig: Figure) -> None:
    width, height = fig.get_size_inches() * SAVE_DPI
    assert max(width, height) <= MAX_SIDE_PX, f"{width:.0f} x {height:.0f} px as saved"


def assert_range_not_set_by_the_start(ax) -> None:
    """Every line's samples at t >= RANGE_FROM lie in the y range, and the range is at most 1.6x
    their spread (so a spike before RANGE_FROM did not set it; the rest is room for the legend)."""
    settled = []
    for line in ax.get_lines():
        t, y = (np.asarray(a, dtype=float) for a in line.get_data())
        if t.size < 10:  # a legend proxy or a marker line
            continue
        keep = (t >= RANGE_FROM) & np.isfinite(y)
        settled.append(y[keep])
    values = np.concatenate(settled)
    low, high = ax.get_ylim()
    assert low <= values.min() and values.max() <= high, "a settled sample is off scale"
    assert high - low <= 1.6 * (values.max() - values.min()) + 1e-12, (
        f"y range {low:.3g}..{high:.3g} for settled data {values.min():.3g}..{values.max():.3g}")


@pytest.fixture(scope="module")
def serial2r_c3(tmp_path_factory) -> Path:
    """A short C3 run on the 2R arm (gravity: Theta has its G entries), the plant changed at j = 2."""
    from ilcforce.config_load import load_config

    config = load_config("serial2r", {"reference.duration": 0.3, "experiment.iterations": 4,
                                      "plant.perturbation.from_iteration": P})
    path = tmp_path_factory.mktemp("runs") / "c3.h5"
    run_method(config, "c3", path)
    return path


def test_the_gravity_figure_answers_its_question_at_the_settled_scale(serial2r_c3: Path) -> None:
    with figures.report_style():
        fig = gravity_figure(serial2r_c3, open_run(serial2r_c3).config)
    assert_small_enough(fig)
    axes = fig.get_axes()
    assert len(axes) == 2
    for ax in axes:
        assert_range_not_set_by_the_start(ax)
        assert "% off J^-T G_q" in ax.get_title(), "the title answers 'does C3 learn gravity?'"
        curves = [line for line in ax.get_lines() if line.get_label().startswith("learned")]
        assert len(curves) == 3, "first, middle and last iteration drawn"
        assert len({(line.get_linestyle(), line.get_linewidth()) for line in curves}) == 3, \
            "each iteration drawn in its own style, so one lying on another stays visible"
    # a sample before 20 ms off scale is named in the legend, and only then
    notes = [text.get_text() for text in fig.legends[0].get_texts() if text.get_text().startswith("off scale")]
    off = 0
    for ax in axes:
        low, high = ax.get_ylim()
        for line in ax.get_lines():
            t, y = (np.asarray(a, dtype=float) for a in line.get_data())
            if t.size >= 10:
                early = y[t < RANGE_FROM]
                off += int(np.any((early < low) | (early > high)))
    assert (off > 0) == (len(notes) > 0), (off, notes)


def test_the_switching_gain_figure_shows_the_settled_alpha_hat(serial2r_c3: Path) -> None:
    metrics = store.read_metrics(serial2r_c3)
    alphas = {j: store.read_memory(serial2r_c3, j)["alpha_hat"] for j in tables.complete_iterations(metrics)}
    duration = float(store.read_reference(serial2r_c3).index.to_numpy()[-1])
    with figures.report_style():
        fig = figures.figure_switching_gain(alphas, duration, perturbation_iteration=P, perturbation_label="m2 x 1.4")
    assert_small_enough(fig)
    profiles, mean = fig.get_axes()
    assert_range_not_set_by_the_start(profiles)
    assert len([line for line in profiles.get_lines() if line.get_label().startswith("j = ")]) == len(alphas)
    marker = [line for line in mean.get_lines() if line.get_label() == f"m2 x 1.4 from j = {P}"]
    assert len(marker) == 1 and list(marker[0].get_xdata()) == [P, P], "a marker at the plant's change"
    settled_max = max(float(np.max(a[figures.control_time(a.size, duration) >= RANGE_FROM])) for a in alphas.values())
    peak = [line for line in mean.get_lines() if line.get_label().startswith("max")][0]
    assert max(peak.get_ydata()) == pytest.approx(settled_max), "the maximum over the settled samples"


def test_fig5_wraps_every_method_into_rows_with_one_number_format() -> None:
    """Seven methods: four to a row (not one row 4,200 px wide), each drawn with its four
    iterations in colours that are not the methods' own, and no axis with an additive offset."""
    import pandas as pd
    from matplotlib.colors import to_hex

    from ilcforce.controllers import REGISTRY

    t = np.linspace(0.0, 2.0, 201)
    methods = list(REGISTRY)[:7]
    assert len(methods) == 7
    frames = {m: {j: pd.DataFrame({"position_error_x": (k + 1) * 1e-6 * np.sin(t * (j + 1)) + 3e-3,
                                   "force_error_y": (k + 1) * 0.01 * np.cos(t)}, index=t)
                  for j in figures.TRACKING_ITERATIONS} for k, m in enumerate(methods)}
    with figures.report_style():
        fig = figures.figure_tracking_error(frames)
        fig.canvas.draw()
    assert_small_enough(fig)
    shown = [ax for ax in fig.get_axes() if ax.get_visible()]
    assert len(shown) == 2 * 7
    assert sorted(ax.get_title() for ax in shown if ax.get_title()) == sorted(figures.method_label(m) for m in methods)
    method_colours = {to_hex(f"C{k}") for k in range(10)}
    for ax in shown:
        lines = ax.get_lines()
        assert [line.get_label() for line in lines] == [f"j = {j}" for j in figures.TRACKING_ITERATIONS]
        assert not {to_hex(line.get_color()) for line in lines} & method_colours
        offset = ax.yaxis.get_offset_text().get_text()
        assert "+" not in offset and "\u2212" not in offset.replace("1e\u2212", ""), offset


def _tidy(methods=("c1", "c2", "c3"), seeds=3, iterations=8) -> "pd.DataFrame":
    import pandas as pd

    rng = np.random.default_rng(0)
    rows = []
    for m, method in enumerate(methods):
        for seed in range(seeds):
            for j in range(iterations):
                size = (m + 1) * 1e-4 * (1 + rng.random()) / (j + 1)
                rows.append({"seed": seed, "method": method, "iteration": j, "status": "complete",
                             "position_error_2norm": size, "force_error_2norm": 100 * size,
                             "position_error_rms": size, "position_error_max": 3 * size,
                             "force_error_rms": 100 * size, "force_error_max": 300 * size})
    return pd.DataFrame(rows)


def test_band_figures_mark_the_plant_s_change_and_draw_every_method() -> None:
    from ilcforce.report import seed_bands, study_figures

    frame = _tidy()
    with figures.report_style():
        norm = study_figures.norm_band_figure(frame, "position_error_2norm", "e_P (m)", "Fig. 3",
                                              perturbation_iteration=4, perturbation_label="m2 x 1.4")
        over_seeds = seed_bands.figure_fig5_over_seeds(frame, perturbation_iteration=4, perturbation_label="m2 x 1.4")
    for fig in (norm, over_seeds):
        assert_small_enough(fig)
        for ax in fig.get_axes():
            verticals = [line for line in ax.get_lines()
                         if len(line.get_xdata()) == 2 and list(line.get_xdata()) == [4, 4]]
            assert verticals, f"no marker at the plant's change in {ax.get_ylabel()!r}"
    labels = [text.get_text() for text in norm.get_axes()[0].get_legend().get_texts()]
    assert "m2 x 1.4 from j = 4" in labels
    assert all(any(text.startswith(figures.method_label(m)) for text in labels) for m in ("c1", "c2", "c3"))


def test_input_figures_leave_no_empty_band_and_keep_the_start_off_scale(serial2r_c3: Path) -> None:
    """Figs. 6, 7: the free band above the data is as tall as the legend it holds (a fixed 45% left
    panel (a) 40% empty), the range comes from t >= 20 ms, every method asked for has its row."""
    last = tables.complete_iterations(store.read_metrics(serial2r_c3))[-1]
    frame = store.read_iteration(serial2r_c3, last)
    for axis in ("x", "y"):
        with figures.report_style():
            fig = figures.figure_input({"c3": frame, "c1": frame}, axis, iterations={"c3": last, "c1": last})
        assert_small_enough(fig)
        axes = fig.get_axes()
        assert len(axes) == 4, "a row per method, (a) and (b)"
        for ax in axes:
            assert_range_not_set_by_the_start(ax)


def assert_legend_clear_of_data(fig: Figure) -> None:
    """No legend of ``fig`` covers a drawn sample, nor the start (t < RANGE_FROM), where the start
    mismatch's spike runs off scale through the whole height of the panel."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    checked = 0
    for ax in fig.get_axes():
        legend = ax.get_legend()
        if legend is None:
            continue
        box = legend.get_window_extent(renderer)
        for line in ax.get_lines():
            t, y = (np.asarray(a, dtype=float) for a in line.get_data())
            if t.size < 10:  # a legend proxy
                continue
            x_px, y_px = ax.transData.transform(np.column_stack([t, y])).T
            start = t < RANGE_FROM
            assert (x_px[start] < box.x0).all(), f"the legend of {ax.get_title() or ax.get_ylabel()!r} is over t = 0"
            inside = (box.x0 <= x_px) & (x_px <= box.x1) & (box.y0 <= y_px) & (y_px <= box.y1)
            assert not inside[~start].any(), f"the legend of {ax.get_title() or ax.get_ylabel()!r} covers data"
            checked += 1
    assert checked, "no legend checked"


def assert_panels_fill_the_width(fig: Figure, share: float = 0.85) -> None:
    """The panels span at least ``share`` of the figure's width: no legend column beside them leaves a
    blank block under it (sweep_key_numbers' legend stood right of the top panel, over nothing below)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    width = fig.bbox.width
    for ax in fig.get_axes():
        box = ax.get_window_extent(renderer)
        assert box.width >= share * width, f"{ax.get_ylabel()!r} spans {box.width / width:.0%} of the width"


def assert_inside_the_canvas(fig: Figure) -> None:
    """Every artist (axis labels, tick labels, titles, legends) inside the figure as drawn: none clipped
    (fig.get_tightbbox against the canvas, in inches)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    tight = fig.get_tightbbox(renderer)
    width, height = fig.get_size_inches()
    slack = 1.0 / fig.dpi  # a pixel
    assert tight.x0 >= -slack and tight.y0 >= -slack, f"drawn beyond the left or bottom edge: {tight}"
    assert tight.x1 <= width + slack and tight.y1 <= height + slack, f"drawn beyond the right or top edge: {tight}"
    for ax in fig.get_axes():  # and the axis labels in particular, each by its own extent
        for label in (ax.xaxis.label, ax.yaxis.label):
            if label.get_text():
                box = label.get_window_extent(renderer)
                assert box.x0 >= -1 and box.y0 >= -1 and box.x1 <= fig.bbox.width + 1 \
                    and box.y1 <= fig.bbox.height + 1, f"axis label {label.get_text()!r} clipped: {box}"


def assert_figure_legends_clear_of_the_panels(fig: Figure) -> None:
    """No figure legend overlaps a panel with its tick and axis labels (each axes' tight box)."""
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    assert fig.legends, "no figure legend"
    for legend in fig.legends:
        box = legend.get_window_extent(renderer)
        for ax in fig.get_axes():
            panel = ax.get_tightbbox(renderer)
            assert not box.overlaps(panel), f"the legend overlaps {ax.get_ylabel() or ax.get_title()!r}"


def test_band_figures_over_seeds_keep_their_labels_with_many_methods() -> None:
    """arm3-mc's Fig. 5 over seeds: nine methods made its legend taller than the fixed bottom margin, so it
    ran over the x-axis labels and off the figure's foot. The margin is measured from the legend now."""
    from ilcforce.report import seed_bands

    methods = ("c1", "c2", "c3", "smc-bl", "pd-ilc", "c3-leak", "sl-adapt", "c2-robust", "c3-robust")
    frame = _tidy(methods=methods, seeds=2, iterations=8)
    for axis in ("x", "y"):
        frame[f"chattering_task_{axis}"] = 0.05
        frame[f"chattering_task_{axis}_no_t0"] = 0.04
        frame[f"chattering_task_{axis}_settled"] = 0.03
    with figures.report_style():
        drawn = [seed_bands.figure_fig5_over_seeds(frame, perturbation_iteration=4, perturbation_label="m2 x 1.4"),
                 seed_bands.figure_input_over_seeds(frame, "y", perturbation_iteration=4, perturbation_label="m2 x 1.4")]
    for fig in drawn:
        assert_inside_the_canvas(fig)
        assert_figure_legends_clear_of_the_panels(fig)


def test_input_figure_legends_stand_clear_of_the_t0_spike() -> None:
    """Fig. 7's legend stood at the upper left, over the spike at t = 0 that runs up off scale (the
    start mismatch); it stands at the right end of the free band above the data now."""
    import pandas as pd

    t = np.linspace(0.0, 2.0, 4001)

    def frame(scale: float, spike: float) -> pd.DataFrame:
        desired = 32 * (t / 2) ** 3 + 8 * np.sin(3 * t)
        actual = desired - scale * np.sin(900 * t) - 0.3 * scale * np.sin(2 * np.pi * t)
        actual[:10] -= spike * np.exp(-np.arange(10) / 2)  # Delta tau = desired - actual: up at t = 0
        return pd.DataFrame({"task_input_y": actual, "desired_task_input_y": desired},
                            index=pd.Index(t, name="time"))

    with figures.report_style():
        fig = figures.figure_input({"c1": frame(1.0, 3.0), "c3": frame(0.03, 1.1)}, "y",
                                   iterations={"c1": 19, "c3": 19})
    assert_legend_clear_of_data(fig)


def test_sweep_key_numbers_mark_a_setting_where_every_seed_diverged(monkeypatch, tmp_path: Path) -> None:
    """C3 at Ts = 1 ms: every seed diverged, so it has no number there; a cross at the foot says so
    (the line used to stop without a mark). H is the settled one, as the claims read it."""
    import json
    from types import SimpleNamespace

    import pandas as pd

    from ilcforce.report import study_figures

    frame = _tidy(methods=("c1", "c3"), seeds=2, iterations=4)
    frame["chattering_task_y_settled"] = 0.05
    frame["chattering_task_y"] = 0.5
    frame["position_error_l2"] = frame["position_error_2norm"]
    frame["force_error_l2"] = frame["force_error_2norm"]
    frames = {0: frame.copy(), 1: frame.copy()}
    lost = frames[1]["method"] == "c3"
    frames[1].loc[lost, ["position_error_l2", "force_error_l2", "chattering_task_y_settled"]] = np.nan
    frames[1].loc[lost & (frames[1]["iteration"] == 0), "status"] = "diverged"
    frames[1] = frames[1][~lost | (frames[1]["iteration"] == 0)]
    config = json.dumps({"experiment": {"iterations": 4}})
    results = SimpleNamespace(
        sweep_keys=["simulation.sample_time"], labelled=False,
        metrics=pd.concat([f.assign(setting=k) for k, f in frames.items()], ignore_index=True),
        settings=pd.DataFrame({"setting": [0, 1], "simulation.sample_time": [1e-4, 1e-3],
                               "config_json": [config, config]}),
        setting_metrics=lambda k: frames[k])
    drawn = {}
    monkeypatch.setattr(study_figures, "save_figure", lambda fig, d, stem, f: drawn.setdefault(stem, fig) and [])
    with figures.report_style():
        study_figures.sweep_figures(results, tmp_path, ("png",))
    fig = drawn["sweep_key_numbers"]
    assert_small_enough(fig)
    for ax in fig.get_axes():
        crosses = [line for line in ax.get_lines() if line.get_marker() == "x" and len(line.get_xdata())]
        assert [list(line.get_xdata()) for line in crosses] == [[1e-3]], ax.get_ylabel()
    assert "settled" in fig.get_axes()[-1].get_ylabel()
    assert any("no seed has the number" in t.get_text() for t in fig.legends[0].get_texts())
    assert_panels_fill_the_width(fig)
    assert_inside_the_canvas(fig)


def test_error_norms_that_coincide_both_show(serial2r_c3: Path) -> None:
    """Two methods with the same numbers (C1 and SMC-BL after the 2R arm's change): the one drawn
    later is narrower, so the earlier one's rim shows around it; every method is drawn."""
    metrics = store.read_metrics(serial2r_c3)
    with figures.report_style():
        fig = figures.figure_error_norm({"c1": metrics, "smc-bl": metrics.copy()}, "position_error_2norm", "e_P (m)",
                                        perturbation_iteration=P, perturbation_label="m2 x 1.4")
    assert_small_enough(fig)
    ax = fig.get_axes()[0]
    first, second = [line for line in ax.get_lines() if line.get_marker() == "o"][:2]
    assert np.array_equal(first.get_ydata(), second.get_ydata())
    assert second.get_markersize() < first.get_markersize() and second.get_linewidth() < first.get_linewidth()
    assert second.get_zorder() > first.get_zorder()
    assert any(list(line.get_xdata()) == [P, P] for line in ax.get_lines()), "a marker at the plant's change"
