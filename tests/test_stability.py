"""The learning-stability test (ilcforce.report.stability) on series whose growth is known."""

import numpy as np
import pandas as pd

from ilcforce.report.stability import MIN_RATE, learning_growth, unstable_methods


def _frame(rates: dict[str, float], seeds=range(5), iterations=20, noise=0.02) -> pd.DataFrame:
    """Tidy rows whose H_x grows by ``rates[method]`` per iteration, with 2% lognormal noise per value."""
    rng = np.random.default_rng(0)
    rows = []
    for method, rate in rates.items():
        for seed in seeds:
            for j in range(iterations):
                value = 0.1 * rate ** j * np.exp(rng.normal(0.0, noise))
                rows.append({"seed": seed, "method": method, "iteration": j, "status": "complete",
                             "chattering_task_x": value})
    return pd.DataFrame(rows)


def test_geometric_growth_is_flagged_and_flat_or_negligible_growth_is_not():
    frame = pd.concat([_frame({"grows": 1.05, "flat": 1.0}), _frame({"creeps": 1.001}, noise=1e-4)])
    growth = learning_growth(frame, perturbation_iteration=10)
    by_method = growth.set_index("method")
    assert by_method.at["creeps", "rate_low"] > 1.0  # the creep is real (noise 0.01%)...
    assert bool(by_method.at["grows", "grows"]) and by_method.at["grows", "growing"] == 5
    assert not bool(by_method.at["flat", "grows"])
    # ... but 0.1% per iteration is below the stated size
    assert not bool(by_method.at["creeps", "grows"]) and MIN_RATE > 1.001
    flags = unstable_methods(growth)
    assert set(flags) == {"grows"} and "H_x x1.05/iteration (5 of 5 seeds)" in flags["grows"]


def test_the_window_excludes_the_jump_at_the_perturbation():
    frame = _frame({"jump": 1.0})
    frame.loc[frame["iteration"] >= 10, "chattering_task_x"] *= 10.0  # a step at p = 10, flat after
    growth = learning_growth(frame, perturbation_iteration=10).set_index("method")
    assert growth.at["jump", "window"] == "j = 11..19"
    assert not bool(growth.at["jump", "grows"])
