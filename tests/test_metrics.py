"""Metrics (docs/model.md#metrics): hand-computed norms, chattering of a known sinusoid, NaN on
divergence, and the convergence iteration.

Tolerances: every expected value here is computed by hand from a few exact inputs, so the only
error is floating-point rounding of a handful of operations; ``rtol=1e-12`` is ~1e4 ulp and
still far below any modelling effect.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from ilcforce.metrics import METRIC_COLUMNS, convergence_iteration, error_norms, iteration_metrics, memory_norms
from ilcforce.records import LOG_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord

RTOL = 1e-12  # a few rounded float64 operations on O(1) numbers


def make_record(
    n_log: int = 5,
    duration: float = 1.0,
    *,
    iteration: int = 0,
    status: str = STATUS_COMPLETE,
    diverged_time: float = math.nan,
    fallback_count: int = 0,
    **signals: np.ndarray,
) -> IterationRecord:
    """An IterationRecord with every LOG_SIGNALS entry: time = linspace(0, duration, n_log),
    (n_log,) for time, (n_log, 2) zeros for the others unless given in ``signals``."""
    log: dict[str, np.ndarray] = {}
    for name, (axes, _unit, _description) in LOG_SIGNALS.items():
        if name == "time":
            log[name] = np.linspace(0.0, duration, n_log)
        else:
            shape = (n_log,) if axes is None else (n_log, len(axes))  # e.g. implicit_fallbacks is scalar
            log[name] = np.asarray(signals.pop(name, np.zeros(shape)), dtype=float)
    assert not signals, f"unknown signals {sorted(signals)}"
    return IterationRecord(
        iteration=iteration,
        status=status,
        diverged_time=diverged_time,
        diverged_reason="" if status == STATUS_COMPLETE else "torque bound exceeded",
        fallback_count=fallback_count,
        log=log,
    )


def test_metric_columns_order_and_units():
    assert list(METRIC_COLUMNS) == [
        "iteration", "status", "fallback_count", "diverged_time",
        "position_error_2norm", "position_error_l2", "position_error_rms", "position_error_max",
        "force_error_2norm", "force_error_l2", "force_error_rms", "force_error_max",
        "chattering_task_x", "chattering_task_y", "chattering_joint_1", "chattering_joint_2",
        # the two further forms of H come after today's columns, so older stores' columns stay a prefix
        "chattering_task_x_no_t0", "chattering_task_x_settled", "chattering_task_y_no_t0",
        "chattering_task_y_settled", "chattering_joint_1_no_t0", "chattering_joint_1_settled",
        "chattering_joint_2_no_t0", "chattering_joint_2_settled",
    ]
    units = {name: unit for name, (unit, _description) in METRIC_COLUMNS.items()}
    assert units["diverged_time"] == "s"
    assert {units[f"position_error_{k}"] for k in ("2norm", "rms", "max")} == {"m"}
    assert {units[f"force_error_{k}"] for k in ("2norm", "rms", "max")} == {"N"}
    # the grid-independent L2 norm carries the square root of time
    assert units["position_error_l2"] == "m s^1/2" and units["force_error_l2"] == "N s^1/2"
    assert units["chattering_task_x"] == units["chattering_task_y"] == "N"
    assert units["chattering_joint_1"] == units["chattering_joint_2"] == "N m"


def test_norms_hand_computed():
    # 5 samples on [0, 1] -> dt = 0.25 s. Position error on x only: sum e^2 = 9 + 16 = 25.
    position_error = np.array([[3.0, 0.0], [0.0, 0.0], [4.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    # Force error on y only: sum e^2 = 4 * 1 = 4.
    force_error = np.array([[0.0, 1.0], [0.0, -1.0], [0.0, 1.0], [0.0, -1.0], [0.0, 0.0]])
    row = iteration_metrics(make_record(position_error=position_error, force_error=force_error))
    expected = {
        "position_error_2norm": 5.0,                  # sqrt(25)
        "position_error_l2": 2.5,                     # sqrt(0.25 * 25)
        "position_error_rms": math.sqrt(5.0),         # sqrt(25 / 5)
        "position_error_max": 4.0,
        "force_error_2norm": 2.0,                     # sqrt(4)
        "force_error_l2": 1.0,                        # sqrt(0.25 * 4)
        "force_error_rms": math.sqrt(0.8),            # sqrt(4 / 5)
        "force_error_max": 1.0,
    }
    for name, value in expected.items():
        np.testing.assert_allclose(row[name], value, rtol=RTOL, err_msg=name)


def test_max_is_euclidean_per_sample_and_both_columns_count():
    error = np.array([[3.0, 4.0], [1.0, 0.0], [0.0, 0.0]])  # |e| = 5, 1, 0; sum e^2 = 26
    norms = error_norms(error, dt=0.5)
    np.testing.assert_allclose(norms["max"], 5.0, rtol=RTOL, err_msg="max of per-sample Euclidean norm")
    np.testing.assert_allclose(norms["2norm"], math.sqrt(26.0), rtol=RTOL, err_msg="2-norm over both columns")
    np.testing.assert_allclose(norms["l2"], math.sqrt(13.0), rtol=RTOL, err_msg="L2 = sqrt(dt * 26)")
    np.testing.assert_allclose(norms["rms"], math.sqrt(26.0 / 3.0), rtol=RTOL, err_msg="rms over 3 samples")


def test_row_keys_types_and_order():
    row = iteration_metrics(make_record(iteration=7, fallback_count=3))
    assert list(row) == list(METRIC_COLUMNS)
    assert row["iteration"] == 7 and isinstance(row["iteration"], int)
    assert row["status"] == STATUS_COMPLETE
    assert row["fallback_count"] == 3 and isinstance(row["fallback_count"], int)
    assert math.isnan(row["diverged_time"])
    assert all(isinstance(row[name], float) for name in list(METRIC_COLUMNS)[4:])


def test_chattering_of_sinusoid_is_its_std():
    # Delta = A sin(2 pi m t / T) sampled at n points including both ends of [0, T]: the samples
    # k = 0 .. n-2 cover m whole periods, so their sum is 0 and their sum of squares (n-1)/2;
    # the last sample is 0. Hence mean 0 and std = A sqrt((n - 1) / (2 n)) exactly.
    n_log, duration = 2001, 2.0
    time = np.linspace(0.0, duration, n_log)
    amplitudes = {"x": 0.06, "y": 0.0534, "1": 0.2, "2": 0.05}
    periods = {"x": 7, "y": 13, "1": 3, "2": 50}

    def wave(axis: str) -> np.ndarray:
        return amplitudes[axis] * np.sin(2 * np.pi * periods[axis] * time / duration)

    # Offsets in desired and applied cancel in the std; they check Delta = desired - applied is used.
    desired_task_input = np.column_stack([wave("x") + 5.0, wave("y") - 3.0])
    task_input = np.column_stack([np.full(n_log, 5.0), np.full(n_log, -3.0)])
    desired_torque = np.column_stack([np.full(n_log, 1.0), np.full(n_log, 2.0)])
    torque = np.column_stack([1.0 - wave("1"), 2.0 - wave("2")])
    row = iteration_metrics(
        make_record(
            n_log,
            duration,
            desired_task_input=desired_task_input,
            task_input=task_input,
            desired_torque=desired_torque,
            torque=torque,
        )
    )
    factor = math.sqrt((n_log - 1) / (2 * n_log))
    # The sums of 2001 sines cancel to ~1e-16 absolute, i.e. ~1e-13 relative to A^2.
    for column, axis in (("chattering_task_x", "x"), ("chattering_task_y", "y"),
                         ("chattering_joint_1", "1"), ("chattering_joint_2", "2")):
        np.testing.assert_allclose(row[column], amplitudes[axis] * factor, rtol=1e-10, err_msg=column)


def test_chattering_of_constant_offset_is_zero():
    n_log = 11
    row = iteration_metrics(make_record(n_log, desired_torque=np.full((n_log, 2), 3.0), torque=np.zeros((n_log, 2))))
    for column in ("chattering_joint_1", "chattering_joint_2", "chattering_task_x", "chattering_task_y"):
        assert row[column] == 0.0, column


def test_diverged_iteration_gets_nan_norms_but_keeps_status():
    n_log = 11
    error = np.ones((n_log, 2))
    error[6:] = np.nan  # the log is NaN after the divergence at t = 0.55 s
    record = make_record(
        n_log, iteration=4, status=STATUS_DIVERGED, diverged_time=0.55, fallback_count=2,
        position_error=error, force_error=error, torque=error,
    )
    row = iteration_metrics(record)
    assert row["iteration"] == 4
    assert row["status"] == STATUS_DIVERGED
    assert row["diverged_time"] == 0.55
    assert row["fallback_count"] == 2
    for name in list(METRIC_COLUMNS)[4:]:
        assert math.isnan(row[name]), f"{name} should be NaN for a diverged iteration"


def test_diverged_gets_nan_even_when_log_is_finite():
    # A diverged iteration is NaN by definition, not only because its log holds NaN.
    row = iteration_metrics(make_record(status=STATUS_DIVERGED, diverged_time=0.5, position_error=np.ones((5, 2))))
    assert math.isnan(row["position_error_2norm"])


def test_bad_record_names_the_signal():
    record = make_record()
    del record.log["force_error"]
    with pytest.raises(ValueError, match="force_error"):
        iteration_metrics(record)
    record = make_record()
    record.log["torque"] = np.zeros((4, 2))
    with pytest.raises(ValueError, match="torque"):
        iteration_metrics(record)


# -- convergence iteration -------------------------------------------------------------------


def test_convergence_monotone():
    norms = [100.0, 50.0, 20.0, 10.0, 6.0, 5.0, 4.9, 4.8, 4.7, 4.6]  # median(5..9) = 4.8
    # threshold 1.5 * 4.8 = 7.2: first j with norm <= 7.2 is j = 4 (6.0)
    assert convergence_iteration(norms) == 4
    # factor 2 -> threshold 9.6: 10.0 is above, so still j = 4
    assert convergence_iteration(norms, factor=2.0) == 4
    # factor 2.1 -> threshold 10.08: j = 3
    assert convergence_iteration(norms, factor=2.1) == 3


def test_convergence_noisy_and_inclusive_threshold():
    # Noisy plateau: median of iterations 5..9 of (3, 1, 2, 5, 4) is 3 -> threshold 4.5.
    norms = [9.0, 4.6, 4.5, 1.0, 2.0, 3.0, 1.0, 2.0, 5.0, 4.0, 50.0]
    # j = 2 has exactly the threshold (inclusive); later values (j = 10) do not matter.
    assert convergence_iteration(norms) == 2


def test_convergence_window_and_last_exact():
    norms = [5.0, 4.0, 3.0, 2.0, 1.0, 1.0]
    # window (3, 5): median(2, 1, 1) = 1, threshold 1.5: first j with norm <= 1.5 is 4.
    assert convergence_iteration(norms, window=(3, 5), last=5) == 4
    # last = 3: no j <= 3 qualifies.
    assert convergence_iteration(norms, window=(3, 5), last=3) is None
    # factor 2 -> threshold 2: j = 3.
    assert convergence_iteration(norms, factor=2.0, window=(3, 5), last=5) == 3


def test_convergence_short_or_nan_sequences():
    assert convergence_iteration([1.0] * 9) is None  # needs iterations 0..9
    assert convergence_iteration([]) is None
    diverged = [10.0, 5.0, 3.0, 2.0, 1.0, 1.0, 1.0, np.nan, np.nan, np.nan]  # diverged at j = 7
    assert convergence_iteration(diverged) is None
    assert convergence_iteration(np.array([1.0] * 10)) == 0  # returns a python int
    assert type(convergence_iteration(np.array([1.0] * 10))) is int


@pytest.mark.parametrize(
    ("kwargs", "argument"),
    [
        ({"factor": 0.9}, "factor"),
        ({"factor": float("nan")}, "factor"),
        ({"window": (9, 5)}, "window"),
        ({"window": (-1, 5)}, "window"),
        ({"window": (1.5, 5)}, "window"),
        ({"last": -1}, "last"),
    ],
)
def test_convergence_rejects_bad_arguments(kwargs, argument):
    with pytest.raises(ValueError, match=argument):
        convergence_iteration([1.0] * 10, **kwargs)


def test_convergence_rejects_2d_norms():
    with pytest.raises(ValueError, match="norms"):
        convergence_iteration(np.ones((10, 2)))


def test_three_forms_of_chattering_hand_computed():
    # 101 samples on [0, 0.1] s (dt = 1 ms). Delta on task x: a spike of 10 at t = 0, then +-1
    # alternating; t >= 20 ms starts at sample 20.
    n = 101
    delta = np.where(np.arange(n) % 2 == 0, 1.0, -1.0)
    delta[0] = 10.0
    desired = np.zeros((n, 2))
    desired[:, 0] = delta
    row = iteration_metrics(make_record(n, 0.1, desired_task_input=desired))
    assert math.isclose(row["chattering_task_x"], float(np.std(delta)), rel_tol=RTOL)
    # without t = 0: samples 1..100, 50 of -1 and 50 of +1 -> std exactly 1
    assert math.isclose(row["chattering_task_x_no_t0"], 1.0, rel_tol=RTOL)
    # settled: samples 20..100, 41 of +1 and 40 of -1 -> mean 1/81, std sqrt(1 - 1/81^2)
    assert math.isclose(row["chattering_task_x_settled"], math.sqrt(1 - 1 / 81**2), rel_tol=RTOL)
    assert row["chattering_task_x"] > 1.0  # the spike alone inflates the whole-grid form
    assert row["chattering_task_y_settled"] == 0.0


def test_settled_window_is_a_parameter():
    n = 101
    desired = np.zeros((n, 2))
    desired[50:, 1] = np.where(np.arange(51) % 2 == 0, 2.0, -2.0)  # +-2 from t = 50 ms on
    desired[:50, 1] = 5.0
    row = iteration_metrics(make_record(n, 0.1, desired_task_input=desired), settled_from=0.05)
    # 26 of +2 and 25 of -2 -> mean 2/51, std 2 sqrt(1 - 1/51^2)
    assert math.isclose(row["chattering_task_y_settled"], 2 * math.sqrt(1 - 1 / 51**2), rel_tol=RTOL)
    with pytest.raises(ValueError, match="settled_from"):
        iteration_metrics(make_record(n, 0.1), settled_from=-1.0)
    # a window beyond the end has fewer than 2 samples: NaN, not a zero that looks like no chattering
    assert math.isnan(iteration_metrics(make_record(n, 0.1), settled_from=1.0)["chattering_task_x_settled"])


def test_memory_norms_hand_computed():
    memory = {"v": np.array([[3.0, 4.0], [0.0, 0.0]]), "alpha_hat": np.array([2.0, 2.0]),
              "broken": np.array([[1.0], [np.nan]])}
    norms = memory_norms(memory)
    assert math.isclose(norms["memory_norm_v"], math.sqrt(25 / 2), rel_tol=RTOL)  # sqrt(mean(25, 0))
    assert math.isclose(norms["memory_norm_alpha_hat"], 2.0, rel_tol=RTOL)
    assert math.isnan(norms["memory_norm_broken"])  # a diverged iteration's unfinished memory


def test_memory_norms_settled_and_at_the_start_keep_the_start_mismatch_apart():
    """A memory whose first sample alone grows (the t = 0 mismatch learned again each iteration):
    the settled norm ignores it, the start norm is that sample, the whole-grid norm mixes both."""
    from ilcforce.metrics import SETTLED_FROM, settled_sample

    assert settled_sample(1e-4) == 200 and settled_sample(1e-3) == 20 and settled_sample(5e-5) == 400
    assert settled_sample(3e-3) == 7, "ceil: the window starts at or after SETTLED_FROM"
    assert SETTLED_FROM == 0.02
    block = np.full((400, 2), 0.3)
    for spike in (1.0, 5.0):
        block[0] = (spike, 0.0)
        norms = memory_norms({"v": block}, settled_from_sample=200)
        assert math.isclose(norms["memory_settled_v"], math.sqrt(0.18), rel_tol=RTOL)  # |(0.3, 0.3)|
        assert math.isclose(norms["memory_start_v"], spike, rel_tol=RTOL)
        assert norms["memory_norm_v"] > norms["memory_settled_v"]
    assert "memory_settled_v" not in memory_norms({"v": block}), "only with a settled window"
    assert math.isnan(memory_norms({"v": block}, settled_from_sample=400)["memory_settled_v"]), "nothing left"
    broken = memory_norms({"v": np.array([[np.nan], [1.0]])}, settled_from_sample=1)
    assert math.isnan(broken["memory_settled_v"]) and math.isnan(broken["memory_start_v"])
