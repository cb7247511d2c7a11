"""The cause account over seeds (ilcforce/report/cause_seeds.py): its summary and sentences from a per-seed
table whose answers are known (synthetic rows, not a study)."""

from __future__ import annotations

import math

import pandas as pd

from ilcforce.report import cause_seeds as cs

NAN = math.nan


def _rows(method, setting, ends, growth=1.02, drift=0.2, run=300):
    return [{"setting": setting, "method": method, "seed": seed, "diverged_at": end,
             "diverged_time_s": 0.001 if math.isfinite(end) else NAN,
             "iterations_run": (int(end) + 1) if math.isfinite(end) else run,
             "settled_growth_per_iteration": growth, "start_drift_per_iteration": drift}
            for seed, end in zip(range(570, 570 + len(ends)), ends)]


def _table(both, tenth, no_noise=(99, 99, 99), disturbance=(NAN, 16, NAN), sensors=(93, 120, NAN), growth_tenth=1.02):
    rows = (_rows("c3", cs.NO_NOISE, no_noise) + _rows("c3", cs.DISTURBANCE, disturbance)
            + _rows("c3", cs.SENSORS, sensors) + _rows("c3", cs.BOTH, both)
            + _rows("c3", cs.TENTH, tenth, growth=growth_tenth))
    return pd.DataFrame(rows)


def test_interaction_is_counted_seed_by_seed_against_every_mechanism_alone():
    # seed 570: both 50 < min(99, never, 93): earlier; 571: both 20 > disturbance's 16: not; 572: 60 < 99: earlier
    lines = cs.account_lines(_table(both=(50, 20, 60), tenth=(120, 40, NAN)))
    first = lines[0]
    assert "diverged on 3 of 3 seeds with no noise, 1 with the disturbance alone, 2 with the sensor noise alone" in first
    assert "3 with both" in first
    assert "before every mechanism alone on 2 of 3 seeds" in first and "interact" in first


def test_no_interaction_is_said_when_no_seed_shows_it():
    lines = cs.account_lines(_table(both=(120, 130, 140), tenth=(150, 160, 170)))
    assert "before every mechanism alone on 0 of 3 seeds." in lines[0] and "interact" not in lines[0]


def test_the_delay_of_a_tenth_of_the_noise_keeps_censored_runs_apart():
    # delays 70 and 20 where both diverged; seed 572 ran every iteration at a tenth: a lower bound, not a number
    delay = cs.account_lines(_table(both=(50, 20, 60), tenth=(120, 40, NAN)))[1]
    assert "by 45 [20, 70] iterations" in delay and "over the 2 seeds" in delay
    assert "on 1 more the run at a tenth did not diverge within 300 iterations" in delay


def test_growth_rates_are_compared_by_their_ranges():
    same = cs.account_lines(_table(both=(50, 20, 60), tenth=(120, 40, NAN)))[2]
    assert "the ranges overlap." in same and "x1.0200 [1.0200, 1.0200]" in same
    apart = cs.account_lines(_table(both=(50, 20, 60), tenth=(120, 40, NAN), growth_tenth=1.005))[2]
    assert "the ranges do not overlap." in apart


def test_the_summary_counts_divergences_and_reads_ranges_over_the_seeds_that_diverged():
    summary = cs.summary_table(_table(both=(50, 20, 60), tenth=(120, 40, NAN))).set_index("setting")
    assert summary.loc[cs.DISTURBANCE, "diverged"] == "1 of 3"
    assert summary.loc[cs.DISTURBANCE, "diverged at j"] == "16 [16, 16]"
    assert summary.loc[cs.TENTH, "diverged at j"] == "80 [40, 120]"
    assert summary.loc[cs.TENTH, "iterations run"] == "121 [41, 300]"


def test_per_seed_rows_read_a_study_the_way_the_page_does():
    """From a constructed study (two settings, two seeds): where each run diverged, and its settled growth."""
    from test_long_run import _Study, _run

    grows = lambda j: 1e-3 * 1.05 ** j  # noqa: E731
    frames = {cs.NO_NOISE: pd.concat([_run("c2", 570, 60, lambda j: 0.1, memory=grows),
                                      _run("c2", 571, 60, lambda j: 0.1, memory=grows, diverge_at=45)]),
              cs.BOTH: pd.concat([_run("c2", 570, 60, lambda j: 0.1, memory=grows, diverge_at=30),
                                  _run("c2", 571, 60, lambda j: 0.1, memory=grows, diverge_at=25)])}
    seeds = cs.per_seed_table(_Study(frames)).set_index(["setting", "seed"])
    assert math.isnan(seeds.loc[(cs.NO_NOISE, 570), "diverged_at"])
    assert seeds.loc[(cs.NO_NOISE, 570), "iterations_run"] == 60
    assert seeds.loc[(cs.NO_NOISE, 571), "diverged_at"] == 45 and seeds.loc[(cs.BOTH, 571), "diverged_at"] == 25
    assert abs(seeds.loc[(cs.NO_NOISE, 570), "settled_growth_per_iteration"] - 1.05) < 1e-9
