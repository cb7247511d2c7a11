"""Figs. 5-7 over seeds: the band statistics and what the figures draw."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from matplotlib.collections import PolyCollection

from ilcforce.report import seed_bands
from ilcforce.report.figures import report_style
from ilcforce.report.study_figures import _bands


@pytest.mark.parametrize("n", [0, 1, 2, 3, 20, 21, 100])
def test_band_row_gives_the_numbers_of_median_interval(n):
    """The sort-based median and the cached resamples must change no number the report prints."""
    rng = np.random.default_rng(n)
    values = np.exp(rng.normal(size=n + 3))
    values[rng.choice(n + 3, size=3, replace=False)] = np.nan  # diverged seeds are dropped
    fast, slow = np.array(seed_bands.band_row(values), float), np.array(_bands(values), float)
    assert np.array_equal(fast, slow, equal_nan=True), (fast, slow)
    ties = np.repeat(values[np.isfinite(values)][:2], 3)  # repeated values (e.g. a discrete j̄)
    assert np.array_equal(np.array(seed_bands.band_row(ties), float), np.array(_bands(ties), float), equal_nan=True)


def _frame(iterations=6, seeds=(0, 1, 2), diverged=None):
    """A tidy frame of one setting: c1 and c3; ``diverged`` = (seed, method, j) stops that cell."""
    rows = []
    rng = np.random.default_rng(7)
    for seed in seeds:
        for method, scale in (("c1", 1.0), ("c3", 0.1)):
            for j in range(iterations):
                status = "complete"
                if diverged and (seed, method) == diverged[:2]:
                    if j > diverged[2]:
                        continue
                    status = "diverged" if j == diverged[2] else status
                row = {"seed": seed, "method": method, "iteration": j, "status": status}
                for column in ("position_error_rms", "position_error_max", "force_error_rms", "force_error_max",
                               "chattering_task_x", "chattering_task_y", "chattering_task_x_no_t0",
                               "chattering_task_y_no_t0", "chattering_task_x_settled", "chattering_task_y_settled"):
                    row[column] = np.nan if status == "diverged" else scale * (1 + j) * rng.uniform(0.8, 1.2)
                rows.append(row)
    return pd.DataFrame(rows)


def test_single_seed_is_a_dashed_line_and_its_divergence_a_vertical_line():
    frame = _frame(diverged=(0, "c3", 3))
    with report_style():
        fig = seed_bands.figure_fig5_over_seeds(frame, perturbation_iteration=4)
    ax = fig.axes[0]
    solid = [line for line in ax.lines if line.get_linestyle() == "-" and len(line.get_xdata()) > 2]
    dashed = [line for line in ax.lines if line.get_linestyle() == "--" and len(line.get_xdata())]
    assert len(solid) == 2 and all(line.get_marker() == "o" for line in solid), "medians: solid, with markers"
    assert len(dashed) == 2 and all(line.get_marker() in ("None", "none", "", None) for line in dashed), \
        "the single seed is dashed and has no marker, so it cannot be taken for the median"
    c3_seed = next(line for line in dashed if line.get_color() == solid[1].get_color())
    assert list(c3_seed.get_xdata()) == [0, 1, 2], "seed 0's C3 stops before its divergence"
    dotted = [line for line in ax.lines if line.get_linestyle() == ":"]
    assert len(dotted) == 1 and list(dotted[0].get_xdata()) == [3, 3], "divergence: a vertical line, not a point"
    assert dotted[0].get_marker() in ("None", "none", "", None)
    assert sum(isinstance(c, PolyCollection) for c in ax.collections) >= 4, "two bands per method"
    labels = fig.legends[0].get_texts()
    assert any("c3" in t.get_text().lower() and "2 of 3 seeds" in t.get_text() for t in labels) or \
        any("2 of 3 seeds" in t.get_text() for t in labels), "the legend counts the seeds left at the end"
    # the bands hold the seeds that did not diverge: at j = 3 the C3 median is over seeds 1 and 2
    mine = frame[(frame["method"] == "c3") & (frame["iteration"] == 3) & (frame["seed"] > 0)]
    assert np.isclose(solid[1].get_ydata()[3], np.median(mine["position_error_rms"]))


def test_inputs_over_seeds_are_the_three_forms_of_h_for_c1_and_c3():
    frame = _frame()
    with report_style():
        fig = seed_bands.figure_input_over_seeds(frame, "y")
    titles = [ax.get_title() for ax in fig.axes]
    assert titles == ["H Y, whole grid", "H Y, without t = 0", "H Y, settled, t >= 20 ms"]
    first = fig.axes[0]
    medians = [line for line in first.lines if line.get_marker() == "o"]
    c3 = frame[(frame["method"] == "c3")].groupby("iteration")["chattering_task_y"].median()
    assert any(np.allclose(line.get_ydata(), c3.to_numpy()) for line in medians)
    assert seed_bands.figure_input_over_seeds(frame[frame["method"] == "c2"], "x") == "no C1 or C3 cells in the study"


def test_band_legends_say_what_the_bands_are_and_name_the_configured_change():
    """The band figures' legends named the methods but not the two shades; and the plant's change was
    always "m3 x 1.4", also on the serial 2R arm whose configuration changes m2."""
    from ilcforce.report.study_figures import DARK_BAND, LIGHT_BAND

    with report_style():
        fig = seed_bands.figure_input_over_seeds(_frame(), "x", perturbation_iteration=4,
                                                 perturbation_label="m2 x 1.4")
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert DARK_BAND in texts and LIGHT_BAND in texts and "m2 x 1.4 from j = 4" in texts, texts
    assert fig.legends[0].get_title().get_text() == "line: median over seeds"


def test_sweep_figure_names_the_unit_of_the_swept_key_and_its_bands(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from ilcforce.report import study_figures

    rows = []
    for setting, ts in enumerate((1e-4, 2.5e-4)):
        frame = _frame(seeds=(0, 1, 2))
        for column in ("position_error_l2", "force_error_l2"):
            frame[column] = frame["position_error_rms"]
        rows.append(frame.assign(setting=setting, **{"simulation.sample_time": ts}))
    metrics = pd.concat(rows, ignore_index=True)
    settings = pd.DataFrame({"setting": [0, 1], "label": ["a", "b"], "simulation.sample_time": [1e-4, 2.5e-4],
                             "config_json": ['{"experiment": {"iterations": 6}}'] * 2})
    results = SimpleNamespace(sweep_keys=["simulation.sample_time"], metrics=metrics, settings=settings,
                              labelled=False,
                              setting_metrics=lambda k: metrics[metrics["setting"] == k].drop(
                                  columns=["setting", "simulation.sample_time"]).reset_index(drop=True))
    drawn = []
    monkeypatch.setattr(study_figures, "save_figure", lambda fig, *args: drawn.append(fig) or [])
    with report_style():
        study_figures.sweep_figures(results, tmp_path, ("png",))
    (fig,) = drawn
    assert fig.axes[-1].get_xlabel() == "simulation.sample_time (s)"
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert study_figures.DARK_BAND in texts and study_figures.LIGHT_BAND in texts
