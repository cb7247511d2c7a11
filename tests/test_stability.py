"""The learning-stability test (ilcforce.report.stability) on series whose growth is known.

Each case is a constructed metrics frame where the right verdict is known: growth over the whole
trajectory must be flagged; growth at the initial sample only, bounded re-learning after the
perturbation, growth below the absolute floor and a run too short to show a trend must not be.
"""

import numpy as np
import pandas as pd

from ilcforce.report.stability import (FLOORS, MIN_RATE, MIN_WINDOW, RELEARN, growth_window, learning_growth,
                                       unstable_methods)

P = 10  # the perturbation iteration of every case


def _frame(series: dict[str, dict[str, object]], seeds=range(5), iterations=60, noise=0.02) -> pd.DataFrame:
    """Tidy rows: ``series[method][column]`` is a function j -> value (2% lognormal noise per value)."""
    rng = np.random.default_rng(0)
    rows = []
    for method, columns in series.items():
        for seed in seeds:
            for j in range(iterations):
                row = {"seed": seed, "method": method, "iteration": j, "status": "complete"}
                for column, f in columns.items():
                    row[column] = f(j) * np.exp(rng.normal(0.0, noise))
                rows.append(row)
    return pd.DataFrame(rows)


def _settled_h(f) -> dict[str, object]:
    return {"chattering_task_x_settled": f, "chattering_task_y_settled": lambda j: 0.03}


def test_growth_over_the_trajectory_is_flagged_and_flat_or_negligible_growth_is_not():
    frame = pd.concat([_frame({"grows": _settled_h(lambda j: 0.03 * 1.05 ** j),
                               "flat": _settled_h(lambda j: 0.03)}),
                       _frame({"creeps": _settled_h(lambda j: 0.03 * 1.001 ** j)}, noise=1e-4)])
    growth = learning_growth(frame, perturbation_iteration=P)
    hx = growth[growth["quantity"] == "chattering_task_x_settled"].set_index("method")
    assert hx.at["creeps", "rate_low"] > 1.0  # the creep is real (noise 0.01%)...
    assert bool(hx.at["grows", "grows"]) and hx.at["grows", "growing"] == 5
    assert not bool(hx.at["flat", "grows"])
    # ... but 0.1% per iteration is below the stated size
    assert not bool(hx.at["creeps", "grows"]) and MIN_RATE > 1.001
    flags = unstable_methods(growth)
    assert set(flags) == {"grows"} and "H_x settled x1.05/iteration (5 of 5 seeds)" in flags["grows"]


def test_growth_at_the_initial_sample_only_is_reported_but_not_flagged():
    """The start mismatch: the memory at t = 0 grows linearly (+0.2 per iteration) and drags the
    whole-grid norm and the whole-grid H with it; over t >= 20 ms everything is flat."""
    at_start = {"memory_start_v": lambda j: 0.2 * (j + 1), "memory_norm_v": lambda j: 0.04 + 0.01 * j,
                "memory_settled_v": lambda j: 0.042, "chattering_task_x": lambda j: 0.06 + 0.02 * j,
                **_settled_h(lambda j: 0.015)}
    growth = learning_growth(_frame({"c2": at_start}), perturbation_iteration=P).set_index("quantity")
    assert unstable_methods(growth.reset_index()) == {}, "drift at one sample is not growth over the trajectory"
    assert growth.at["memory_start_v", "rate"] > MIN_RATE and not growth.at["memory_start_v", "judged"]
    assert not bool(growth.at["memory_start_v", "grows"]), "the initial sample is reported on its own, not judged"
    assert growth.at["chattering_task_x", "rate_low"] > MIN_RATE and not bool(growth.at["chattering_task_x", "grows"])
    assert growth.at["memory_settled_v", "judged"] and not bool(growth.at["memory_settled_v", "grows"])


def test_growth_of_the_settled_memory_and_chattering_is_flagged():
    """Noise integrated into the memory over the whole trajectory: settled H_x 0.038 -> 0.6 N over
    70 iterations (4% per iteration, as C3's in the long run) and its settled memory with it."""
    spread = {"memory_settled_theta_hat": lambda j: 0.59 * 1.04 ** j, **_settled_h(lambda j: 0.038 * 1.04 ** j)}
    flags = unstable_methods(learning_growth(_frame({"c3": spread}, iterations=80), perturbation_iteration=P))
    assert set(flags) == {"c3"}
    assert "H_x settled" in flags["c3"] and "|theta_hat| settled" in flags["c3"]


def test_bounded_relearning_after_the_perturbation_is_not_flagged():
    """Settled H doubles at the m3 change and rises to a new plateau over ~5 iterations: bounded."""
    def relearn(j: int) -> float:
        return 0.03 if j < P else 0.06 + 0.04 * (1.0 - np.exp(-(j - P) / 3.0))

    frame = _frame({"c3": _settled_h(relearn)}, iterations=40, noise=1e-3)
    growth = learning_growth(frame, perturbation_iteration=P).set_index("quantity")
    first = int(growth.at["chattering_task_x_settled", "window"].split("= ")[1].split("..")[0])
    assert first >= P + RELEARN, "re-learning after the perturbation is never in the window"
    assert unstable_methods(growth.reset_index()) == {}


def test_growth_below_the_absolute_floor_is_not_flagged():
    """Settled H_x growing 5% per iteration but ending at 0.01 N, below the 0.02 N floor."""
    small = _settled_h(lambda j: 0.01 * 1.05 ** (j - 59))
    growth = learning_growth(_frame({"c2": small}), perturbation_iteration=P).set_index("quantity")
    assert growth.at["chattering_task_x_settled", "rate_low"] > MIN_RATE
    assert growth.at["chattering_task_x_settled", "value_end"] <= FLOORS["chattering_task_x_settled"]
    assert not bool(growth.at["chattering_task_x_settled", "grows"])


def test_a_run_too_short_to_show_a_trend_is_not_evaluable():
    """The paper's 20 iterations leave 5 after the re-learning allowance: no rate is fitted."""
    assert growth_window(list(range(20)), P) == []
    assert growth_window(list(range(P + RELEARN + MIN_WINDOW)), P) == list(range(P + RELEARN, P + RELEARN + MIN_WINDOW))
    assert growth_window(list(range(150)), P) == list(range(82, 150)), "the later half of j = 15..149"
    growth = learning_growth(_frame({"c3": _settled_h(lambda j: 0.03 * 1.2 ** j)}, iterations=20),
                             perturbation_iteration=P)
    assert growth.empty and unstable_methods(growth) == {}


def test_one_seed_reports_its_own_fit_interval():
    """A single run (or a deterministic setting's one evaluation): the rate's interval is the fit's
    95% t interval, not a degenerate bootstrap over one value."""
    growth = learning_growth(_frame({"c3": _settled_h(lambda j: 0.03 * 1.05 ** j)}, seeds=[0]), perturbation_iteration=P)
    row = growth.set_index("quantity").loc["chattering_task_x_settled"]
    assert row["rate_low"] < row["rate"] < row["rate_high"] and row["fitted"] == 1
    assert row["rate_low"] > MIN_RATE and bool(row["grows"])
