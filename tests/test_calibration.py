"""The calibration of noise.scale to Table 2: the fit per assumed grid, its bootstrap interval over
seeds, the text that prints it, and the command (docs/model.md#calibration).

Synthetic seeds: C2's norms are Table 2's times ``factor_s * (scale / true_scale) ** power``, one
factor per seed, log-symmetric about 1 over an odd number of seeds, so the median over seeds is
exactly Table 2's at ``true_scale``. With power 1 (norms proportional to the scale) every answer is
known in closed form: the level on a grid of N samples is true_scale * sqrt(N_ours / N) (Table 2's
norm on N samples is sqrt(N / N_ours) ours for the same RMS), a seed fitted alone lands at
true_scale / factor_s, and its ratio at the point fit is factor_s.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import calibration, calibration_fit, paper
from ilcforce.report.calibration_fit import Grid

OURS = 2001
TRUE = 0.04
FACTORS = np.exp(np.linspace(-0.4, 0.4, 11))  # 11 seeds; median exactly 1
#: The fitted level is written with DIGITS significant figures: it may sit half a unit of the second
#: figure from the unrounded optimum, at most 5% of it (leading digit 1).
ROUNDING = 0.5 * 10.0 ** (1 - calibration_fit.DIGITS)
#: The fine grid's step in log(level) over the swept 0.003-1 (FINE_POINTS points), as a relative error.
FINE_STEP = math.log(1.0 / 0.003) / (calibration_fit.FINE_POINTS - 1)


def _seeds(power: float = 1.0, true_scale: float = TRUE, factors=FACTORS) -> pd.DataFrame:
    rows = []
    for scale in np.geomspace(0.003, 1.0, 11):
        for method in ("c1", "c2", "c3"):
            row = paper.table2_row(method)
            for quantity, column, _unit in calibration.QUANTITIES:
                level = getattr(row, column) if row is not None else 1.0
                for seed, factor in enumerate(factors):
                    rows.append({"noise_scale": scale, "method": method, "quantity": quantity, "seed": seed,
                                 "value": level * factor * (scale / true_scale) ** power})
    return pd.DataFrame(rows)


def test_table_2_on_a_finer_grid_is_a_smaller_norm_on_ours() -> None:
    # the same RMS over 4x the samples: a 2-norm twice ours, so Table 2's value stands for half on ours
    assert calibration_fit.table2_on_our_grid(1.0, 4 * OURS, OURS) == pytest.approx(0.5, rel=1e-12)
    assert calibration_fit.table2_on_our_grid(7.6e-6, OURS, OURS) == 7.6e-6
    assert [g.samples for g in calibration_fit.grids(OURS)] == [201, 2001, 20001]
    assert [g.samples for g in calibration_fit.grids(OURS) if g.samples == OURS][0] == OURS
    assert [g.samples for g in calibration_fit.grids(1001)] == [201, 1001, 2001, 20001]  # ours added, said as ours


def test_the_fit_on_our_grid_finds_the_level_where_c2_matches_and_its_interval_holds_it() -> None:
    fit = calibration_fit.fit_grid(_seeds(0.8), Grid(OURS, "1 ms", "ours"), OURS, n_boot=400)
    assert fit is not None and fit.is_ours and not fit.at_edge
    assert fit.scale == pytest.approx(TRUE, rel=ROUNDING)
    assert fit.low < fit.scale < fit.high, (fit.low, fit.scale, fit.high)
    assert fit.position_only == pytest.approx(TRUE, rel=2 * FINE_STEP)
    for quantity in ("position", "force"):
        ratio = fit.ratios[("c2", quantity)]
        assert ratio.low < ratio.estimate < ratio.high and ratio.low < 1.0 < ratio.high
        assert ratio.estimate == pytest.approx(1.0, rel=0.8 * ROUNDING)  # 1 at TRUE, scale within ROUNDING of it


def test_the_grid_scaling_moves_the_level_by_the_square_root_of_the_sample_ratio() -> None:
    seeds = _seeds(1.0)
    # 4x our samples: Table 2 stands for half its value on our grid; norms proportional to the scale
    # reach that at half the level, exactly 0.02
    fine = calibration_fit.fit_grid(seeds, Grid(4 * OURS, "x", "test"), OURS, n_boot=200)
    coarse = calibration_fit.fit_grid(seeds, Grid(OURS // 4, "y", "test"), OURS, n_boot=200)
    assert fine.scale == pytest.approx(0.02, rel=2 * FINE_STEP)
    assert coarse.scale == pytest.approx(TRUE * math.sqrt(OURS / (OURS // 4)), rel=ROUNDING)
    # the shipped grids: fewer samples, a higher level, by sqrt of the ratio
    fits = {f.grid.samples: f for f in calibration_fit.fit_grids(seeds, OURS, n_boot=200)}
    for samples, fit in fits.items():
        assert fit.scale == pytest.approx(TRUE * math.sqrt(OURS / samples), rel=ROUNDING), samples
        assert fit.low <= fit.scale <= fit.high
    assert fits[201].scale > fits[2001].scale > fits[20001].scale
    # with norms ~ scale^0.8 the level moves by the ratio^(1 / (2 * 0.8)): further, as a flatter curve must
    curved = calibration_fit.fit_grid(_seeds(0.8), Grid(4 * OURS, "x", "test"), OURS, n_boot=50)
    assert curved.scale == pytest.approx(TRUE * 0.5 ** (1 / 0.8), rel=ROUNDING)


def test_each_seed_fitted_alone_and_its_ratio_at_the_fit_are_its_own() -> None:
    fit = calibration_fit.fit_grid(_seeds(1.0), Grid(OURS, "1 ms", "ours"), OURS, n_boot=200)
    assert fit.seeds == tuple(range(len(FACTORS)))
    np.testing.assert_allclose(fit.seed_scales, TRUE / FACTORS, rtol=2 * FINE_STEP,
                               err_msg="a seed whose norms are factor x the median's matches at TRUE / factor")
    np.testing.assert_allclose(fit.ratios[("c2", "position")].per_seed, FACTORS * fit.scale / TRUE, rtol=1e-9)
    assert min(fit.seed_scales) < fit.low <= fit.high < max(fit.seed_scales)  # the median's interval is narrower


def test_a_diverged_seed_is_dropped_and_no_c2_means_no_fit() -> None:
    seeds = _seeds(1.0)
    seeds.loc[(seeds["seed"] == 0) & (seeds["noise_scale"] > 0.5), "value"] = math.nan
    fit = calibration_fit.fit_grid(seeds, Grid(OURS, "1 ms", "ours"), OURS, n_boot=100)
    assert fit is not None and math.isfinite(fit.seed_scales[0]) and math.isfinite(fit.low)
    assert calibration_fit.fit_grid(seeds[seeds["method"] != "c2"], Grid(OURS, "1 ms", "ours"), OURS) is None
    assert calibration.calibrate(seeds.iloc[:0], OURS) is None


@pytest.mark.parametrize(("estimate", "low", "high", "text"), [
    (1.0, 0.7, 1.2, "1.0 [0.7, 1.2]"),            # half-width 0.25: one decimal, not "1.00"
    (1.0397, 1.001, 1.074, "1.04 [1.00, 1.08]"),  # half-width 0.036: two; bounds rounded outward
    (0.04, 0.0341, 0.0499, "0.040 [0.034, 0.050]"),
    (13.2, 9.1, 17.3, "13 [9, 18]"),
    (0.04, 0.04, 0.04, "0.040 [0.040, 0.040]"),   # one seed: two significant figures
])
def test_a_number_is_printed_to_no_more_digits_than_its_interval_supports(estimate, low, high, text) -> None:
    assert calibration.shown(estimate, low, high) == text


def test_the_text_gives_every_match_with_its_interval_and_every_grid() -> None:
    found = calibration.calibrate(_seeds(0.8), OURS, n_boot=300)
    text = found.text()
    assert text.startswith("C2 at noise.scale 0.04")
    assert re.search(r"position \d\.\d+ \[\d\.\d+, \d\.\d+\] of Table 2, force \d\.\d+ \[", text), text
    assert "x Table" not in text and not re.search(r"\d\.\d+x", text), "no match without its interval"
    assert "2001 samples" in text and "20001 samples" in text and "201 samples" in text
    assert "11 seeds" in text
    summary = found.summary()  # the findings summary's shorter line says the same with its intervals
    assert summary.startswith(text.split(":", 1)[0]) and len(summary) < len(text) / 2
    assert re.search(r"position \d\.\d+ \[\d\.\d+, \d\.\d+\] of Table 2", summary), summary
    assert "0.1 ms 0.0" in summary and "10 ms 0." in summary and not re.search(r"\d\.\d+x", summary)
    table = found.table()
    assert list(table["samples"]) == [201, 2001, 20001]
    rows = found.rows()
    assert set(rows["row"]) == {"fit", "seed"} and len(rows) == 3 * (1 + len(FACTORS))
    ours = rows[(rows["samples"] == OURS) & (rows["row"] == "fit")].iloc[0]
    assert ours["noise_scale_low"] <= ours["noise_scale"] <= ours["noise_scale_high"]
    toml = calibration.calibrated_toml(found, "x.h5")
    assert 'name = "paper-calibrated"' in toml and "scale = 0.04\n" in toml


class _Results:
    """A calibration study's results as the reader gives them: settings and tidy metrics per setting,
    C2's (and C1's, C3's) norms from :func:`_seeds` over iterations 0..9 on a grid of ``samples``."""

    sweep_keys = ["noise.scale"]
    labelled = False

    def __init__(self, samples: int = OURS) -> None:
        self.values = _seeds(1.0)
        levels = sorted(self.values["noise_scale"].unique())
        self.settings = pd.DataFrame({"noise.scale": levels}, index=pd.Index(range(len(levels)), name="setting"))
        self.samples = samples

    def setting_metrics(self, setting: int) -> pd.DataFrame:
        scale = self.settings.loc[setting, "noise.scale"]
        part = self.values[self.values["noise_scale"] == scale]
        wide = part.pivot_table(index=["seed", "method"], columns="quantity", values="value").reset_index()
        rows = []
        for iteration in range(10):
            for _, r in wide.iterrows():
                rows.append({"seed": int(r["seed"]), "method": r["method"], "iteration": iteration, "status": "complete",
                             "position_error_2norm": r["position"], "force_error_2norm": r["force"],
                             "position_error_rms": r["position"] / math.sqrt(self.samples)})
        return pd.DataFrame(rows)


def test_the_study_report_writes_the_norms_the_fit_per_grid_and_seed_and_the_figure(tmp_path) -> None:
    results = _Results()
    assert calibration.is_calibration_study(results)
    assert calibration_fit.our_samples(results) == OURS
    assert calibration_fit.our_samples(_Results(1001)) == 1001  # read from the store, not assumed
    written, lines, found = calibration.write_calibration(results, tmp_path)
    assert sorted(p.name for p in written) == ["calibration.csv", "calibration_fit.csv", "fig_calibration.png"]
    assert found.scale == pytest.approx(TRUE, rel=ROUNDING)
    fit = pd.read_csv(tmp_path / "calibration_fit.csv")
    assert sorted(fit.loc[fit["row"] == "fit", "samples"]) == [201, 2001, 20001]
    assert (fit["row"] == "seed").sum() == 3 * len(FACTORS)
    assert found.text() in lines and any(line.startswith("| Table 2's grid") for line in lines)
    norms = pd.read_csv(tmp_path / "calibration.csv")
    c2 = norms[(norms["method"] == "c2") & (norms["quantity"] == "position")]
    np.testing.assert_allclose(c2["median"], 7.6e-6 * c2["noise_scale"] / TRUE, rtol=1e-12)


def test_the_calibration_command_refuses_bad_input_in_one_line(tmp_path, capsys) -> None:
    assert calibration.main([]) == 2
    missing = tmp_path / "none.h5"
    assert calibration.main([str(missing)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"{missing}: not a readable study store"), err


def test_the_command_prints_every_grid_and_writes_only_a_calibrated_file(tmp_path, monkeypatch, capsys) -> None:
    import ilcforce.study

    monkeypatch.setattr(ilcforce.study, "read_study", lambda path: _Results())
    assert calibration.main(["s.h5"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("C2 at noise.scale 0.04") and "| 0.1 ms | 20001 |" in out, out
    found = calibration.from_results(_Results())[1]
    other = tmp_path / "paper.toml"
    other.write_text("[experiment]\nname = 'paper'\n")
    assert calibration.main(["s.h5", "--write", str(other)]) == 2
    assert other.read_text() == "[experiment]\nname = 'paper'\n", "a file of another kind is never replaced"
    target = tmp_path / "paper-calibrated.toml"
    assert calibration.main(["s.h5", "--write", str(target)]) == 0
    assert target.read_text() == calibration.calibrated_toml(found, "s.h5")
    before = target.stat().st_mtime_ns
    assert calibration.main(["s.h5", "--write", str(target)]) == 0
    assert "unchanged" in capsys.readouterr().out and target.stat().st_mtime_ns == before
