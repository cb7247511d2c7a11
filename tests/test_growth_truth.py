"""The three-class truth of the growth test's validation (ilcforce.report.growth_validation.truth_3_of): what a
run of 1,000 iterations shows, decided by the largest growth of every quantity the test judges, with a middle
class ("slow") that counts as neither a miss nor a false alarm."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import growth_validation as gv


def _run(end: float, *, name: str = "v", settled_end: float = 1.0, start: float = 1.0, diverged: int | None = None,
         iterations: int = 1000) -> pd.DataFrame:
    """A run whose t = 0 memory goes linearly from ``start`` at j = 20 to ``end`` at its last iteration while H and
    the settled memory stay flat (``settled_end`` at the end)."""
    j = np.arange(iterations)
    drift = start + (end - start) * np.clip((j - 20) / (iterations - 1 - 20), 0.0, None)
    frame = pd.DataFrame({"iteration": j, "status": "complete", "chattering_task_x_settled": 0.5,
                          "chattering_task_y_settled": 0.2, f"memory_settled_{name}": np.linspace(1.0, settled_end, j.size),
                          f"memory_norm_{name}": 2.0, f"memory_start_{name}": drift})
    if diverged is not None:
        frame = frame[frame["iteration"] <= diverged].copy()
        frame.loc[frame["iteration"] == diverged, "status"] = "diverged"
    return frame


@pytest.mark.parametrize("end, expected", [(3.0, "bounded"), (5.0, "bounded"), (5.5, "slow"), (20.0, "slow"),
                                           (21.0, "unbounded"), (3000.0, "unbounded")])
def test_the_largest_growth_of_any_judged_quantity_decides_with_a_slow_band_between_5x_and_20x(end, expected):
    truth, reason, growth = gv.truth_3_of(_run(end), "c2-robust")
    assert truth == expected
    assert growth == pytest.approx(end)
    assert reason.startswith("|v| t = 0 x")


def test_a_diverged_run_is_unbounded_whatever_grew():
    truth, reason, _ = gv.truth_3_of(_run(1.0, diverged=300), "c2")
    assert (truth, reason) == ("unbounded", "diverged at j = 300")


def test_a_memory_the_law_caps_and_one_of_round_off_size_are_not_counted():
    capped = _run(100.0, name="alpha_hat")
    assert gv.truth_3_of(capped, "c3-robust", {"c3-robust": {"alpha_max": 0.03}})[0] == "bounded"
    assert gv.truth_3_of(capped, "c3-robust", {})[0] == "unbounded"  # no cap configured: it counts
    # a t = 0 memory grown 1000x to 1e-9 of a settled memory of 1: numerical residue, not learning
    residue = _run(1e-9, start=1e-12)
    assert gv.truth_3_of(residue, "c2-robust")[0] == "bounded"
    # the same growth to 1e-3 of the settled memory is learning, and counts
    assert gv.truth_3_of(_run(1e-3, start=1e-6), "c2-robust")[0] == "unbounded"


def test_settled_h_on_a_spatial_tasks_axes_counts():
    """The frozen truth read settled H on x and y only; the three-class truth reads every task axis the test judges."""
    frame = _run(1.0).drop(columns=["chattering_task_x_settled", "chattering_task_y_settled"])
    frame["chattering_task_n_settled"] = np.where(frame["iteration"] >= 20, 0.1 * (1 + frame["iteration"] / 20.0), 0.1)
    truth, reason, growth = gv.truth_3_of(frame, "c2")
    assert truth == "unbounded" and reason.startswith("H_n settled") and growth == pytest.approx(5.095 / 0.2)


def test_slow_cases_are_counted_apart_never_as_misses_or_false_alarms():
    h = gv.STATED_HORIZON
    rows = [{"method": "c2-robust", "setting": "Q", "seed": 700, "truth_3": truth, "truth_reason_3": "x",
             "diverged_at": float("nan"), f"verdict_{h}": verdict}
            for truth, verdict in [("unbounded", "flagged"), ("unbounded", "flagged"), ("slow", "flagged"),
                                   ("slow", "not flagged"), ("slow", "flagged"), ("bounded", "not flagged")]
            + [("bounded", "not flagged")] * 9]
    cases = pd.DataFrame(rows)
    shares = gv.rates(cases, h, "truth_3").set_index("what")
    assert shares.loc["misses", ["count", "of"]].tolist() == [0, 2]
    assert shares.loc["false alarms", ["count", "of"]].tolist() == [0, 10]
    slow = shares.loc["slow cases flagged (neither right nor wrong)"]
    assert [slow["count"], slow["of"]] == [2, 3]
    assert gv.target_text(cases, h, "truth_3").startswith("met: 0 of 2")
    assert gv.confusion(cases, h, "truth_3").index.tolist() == ["unbounded", "slow", "bounded"]
    assert "3 slow (2 flagged, neither right nor wrong)" in gv.confusion_text(cases, h, "truth_3")
    # without slow cases the matrix and the counts are the two-class ones
    two = cases[cases["truth_3"] != "slow"]
    assert gv.confusion(two, h, "truth_3").index.tolist() == ["unbounded", "bounded"]
    assert "slow" not in " ".join(gv.rates(two, h, "truth_3")["what"])


def _memory_run(iterations: int) -> pd.DataFrame:
    """A t = 0 memory growing 5% per iteration over j = 50..99, then 0.5% per iteration: H and the settled memory flat."""
    j = np.arange(iterations)
    log_rate = np.where(j < 50, 0.0, np.where(j < 100, np.log(1.05), np.log(1.005)))
    start = 1e-3 * np.exp(np.cumsum(log_rate))
    return pd.DataFrame({"seed": 0, "method": "c2-robust", "iteration": j, "status": "complete",
                         "chattering_task_x_settled": 0.5, "chattering_task_y_settled": 0.2,
                         "memory_settled_v": 0.04, "memory_norm_v": 0.1, "memory_start_v": start})


def test_a_long_run_is_also_read_at_its_midpoint():
    """Growth that slows inside the later half's window is caught by the reading of the run's first half
    (the third held-out set's robust laws); at 200 iterations the later half alone (j = 104..199, 0.5% per
    iteration) finds nothing."""
    from ilcforce import stability

    assert stability.readings(list(range(200)), 10) == [list(range(104, 200)), list(range(54, 100))]
    assert len(stability.readings(list(range(99)), 10)) == 1  # shorter than MIDPOINT_FROM: one reading
    said, text = stability.verdict_of(_memory_run(200), "c2-robust", 200, 10)
    assert said == stability.FLAGGED and text.startswith("|v| t = 0 grows x1.05")
    growth = stability.learning_growth(_memory_run(200), perturbation_iteration=10)
    assert growth.set_index("quantity").loc["memory_start_v", "window"] == "j = 54..99"
    # the later window alone does not flag it: what the test said before the midpoint reading
    later = stability.growth_window(list(range(200)), 10)
    values = _memory_run(200)["memory_start_v"].to_numpy()[later]
    assert stability.growth_rate(values, iterations=later).low < stability.MIN_RATE
