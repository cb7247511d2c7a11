"""NO-ILC (ilcforce/controllers/no_ilc.py): the norm-optimal update against its closed form on small linear
systems, monotone decrease of the error for a linear plant, the Q filter on the memory, the gains' one-line
errors, and the lifted model of the nominal closed loop predicting what the simulator does.

The registry's contract test (tests/test_method_registry.py) runs it on every plant, deterministic and resumable.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ilcforce.controllers.no_ilc import NOILCController, NOILCGains, hat_basis, knot_count, norm_optimal_gain
from ilcforce.controllers.robust import QFilter
from ilcforce.records import STATUS_COMPLETE


def _causal_model(rng, n_err: int, n_coef: int) -> np.ndarray:
    """A random lower-triangular-ish G (a causal plant: coefficient c reaches the errors from its own row on)."""
    model = rng.standard_normal((n_err, n_coef))
    rows = np.arange(n_err)[:, None] * n_coef // n_err
    return np.where(rows >= np.arange(n_coef)[None, :], model, 0.0)


@pytest.mark.parametrize("axes", [1, 2, 3])
def test_the_gain_is_the_closed_form_minimiser(axes):
    """L e minimises ||e - G dc||_Q^2 + ||dc||_R^2: it equals (G^T Q G + R)^-1 G^T Q e, written out, and the
    cost's gradient vanishes there (tolerance: round-off of a solve of condition < 1e6)."""
    rng = np.random.default_rng(axes)
    model = _causal_model(rng, 12 * axes, 4 * axes)
    weights = rng.uniform(0.5, 2.0, 12 * axes)
    r = 0.3
    gain = norm_optimal_gain(model, weights, r, axes)
    Q = np.diag(weights)
    normal = model.T @ Q @ model
    rho = [np.median(np.diag(normal)[i * 4:(i + 1) * 4]) for i in range(axes)]
    R = r * np.diag(np.repeat(rho, 4))
    np.testing.assert_allclose(gain, np.linalg.inv(normal + R) @ model.T @ Q, rtol=1e-10, atol=1e-12,
                               err_msg="L is not (G^T Q G + R)^-1 G^T Q")
    e = rng.standard_normal(12 * axes)
    dc = gain @ e
    gradient = -model.T @ Q @ (e - model @ dc) + R @ dc
    np.testing.assert_allclose(gradient, 0.0, atol=1e-10, err_msg="the update is not the cost's minimiser")


def test_the_error_of_a_linear_plant_decreases_monotonically():
    """On a linear plant e_j = y_d - G c_j with the exact model, norm-optimal ILC never increases ||e||_Q
    (Amann, Owens & Rogers 1996): ||e_{j+1}||_Q^2 + ||dc_j||_R^2 <= ||e_j||_Q^2 since dc = 0 is a candidate.
    Here the target is reachable, so the error also goes to zero, as fast as the slowest mode of
    c* - c_{j+1} = (G^T Q G + R)^-1 R (c* - c_j) allows: its spectral radius is 0.94 here, 0.94^300 ~ 1e-8."""
    rng = np.random.default_rng(7)
    model = _causal_model(rng, 30, 10)
    weights = rng.uniform(0.5, 2.0, 30)
    target = model @ rng.standard_normal(10)  # reachable: the limit error is zero
    gain = norm_optimal_gain(model, weights, 0.1)
    c = np.zeros(10)
    norms = []
    for _ in range(300):
        e = target - model @ c
        norms.append(float(np.sqrt(e @ (weights * e))))
        c = c + gain @ e
    assert all(b <= a * (1 + 1e-12) for a, b in zip(norms, norms[1:])), f"||e||_Q rose: {norms[:10]}"
    assert norms[-1] < 1e-6 * norms[0], f"the reachable error did not vanish: {norms[0]:.3g} -> {norms[-1]:.3g}"


def test_hat_basis_interpolates_the_coefficients():
    basis = hat_basis(101, 11)
    np.testing.assert_allclose(basis.sum(axis=1), 1.0, rtol=0, atol=1e-15, err_msg="the hats are a partition of one")
    c = np.linspace(-1.0, 3.0, 11) ** 2
    np.testing.assert_allclose(basis @ c, np.interp(np.linspace(0, 1, 101), np.linspace(0, 1, 11), c), atol=1e-14)
    assert knot_count("no-ilc", 20001, 1e-4, 0.02) == 101


class _Surface:
    selection = (0.0, 1.0)
    lambda_p = (2.0, 0.0)
    lambda_f1 = (0.0, 0.001)
    lambda_f2 = (0.0, 0.0001)


class _Record:
    diverged = False


def _controller(model, **gains) -> NOILCController:
    """A controller on a 0.01 s horizon (101 samples at Ts = 1e-4, log every 10: 11 error rows per axis) whose
    lifted model is ``model`` (given, not simulated)."""
    settings = NOILCGains(**{"knot_spacing": 0.002, **gains})  # 6 knots per axis
    return NOILCController(101, _Surface(), 1.0, settings, sample_time=1e-4, lifted_model=lambda _c: model,
                           log_every=10)


def test_the_controller_applies_the_closed_form_update():
    """Without Q (q_cutoff = 0) the memory iteration j + 1 reads is u_j + Phi L e_j, L of the closed form; the
    measured error of iteration j stays beside it."""
    rng = np.random.default_rng(3)
    model = _causal_model(rng, 22, 12)
    controller = _controller(model, q_cutoff=0.0)
    mem_prev, mem_new = controller.begin_iteration(0)
    u_j = rng.standard_normal((101, 2))
    error = rng.standard_normal((101, 2))
    mem_new[:, :2], mem_new[:, 2:] = u_j, error  # what the law writes: u_j and the measured error
    controller.end_iteration(_Record())
    weights = np.tile([1.8e8, 1.0], 11)
    dc = norm_optimal_gain(model, weights, 0.1, 2) @ error[::10].ravel()
    basis = hat_basis(101, 6)
    expected = u_j + np.column_stack([basis @ dc[:6], basis @ dc[6:]])
    state = controller.learned_state()
    np.testing.assert_allclose(state["u"], expected, rtol=1e-12, atol=1e-12, err_msg="u_{j+1} is not u_j + Phi L e_j")
    np.testing.assert_array_equal(state["error"], error)


def test_the_memory_is_q_filtered():
    """With Q on, u_{j+1} = Q[u_j + Phi L e_j]: the zero-phase Butterworth of the robust variants. On a 0.2 s
    horizon it removes a 1 kHz ripple from the memory away from the ends (a 2nd-order filter at 50 Hz, run
    twice, leaves (50 / 1000)^4 ~ 6e-6 of it; 1e-3 is a loose bound; within 20 ms of either end the filter's
    start-up transient, about 3 ms long, is not judged) and passes a constant."""
    settings = NOILCGains(q_cutoff=50.0)
    controller = NOILCController(2001, _Surface(), 1.0, settings, sample_time=1e-4,
                                 lifted_model=lambda _c: _causal_model(np.random.default_rng(4), 402, 22), log_every=10)
    _prev, mem_new = controller.begin_iteration(0)
    t = np.arange(2001) * 1e-4
    ripple = np.sin(2 * np.pi * 1000.0 * t)
    mem_new[:, 0], mem_new[:, 1] = 1.0 + ripple, ripple
    mem_new[:, 2:] = 0.0  # no error: the update adds nothing, only Q acts
    before = mem_new[:, :2].copy()
    controller.end_iteration(_Record())
    u = controller.learned_state()["u"]
    np.testing.assert_allclose(u, QFilter("no-ilc", 50.0, 2, 1e-4).apply(before), rtol=0, atol=1e-15)
    inside = slice(200, -200)
    assert np.max(np.abs(u[inside, 1])) < 1e-3, "the ripple passed the Q filter"
    np.testing.assert_allclose(u[inside, 0], 1.0, atol=1e-3, err_msg="Q does not pass a constant")


def test_a_diverged_iteration_hands_on_nothing():
    controller = _controller(np.eye(22, 12), q_cutoff=0.0)
    before = controller.learned_state()["u"].copy()
    _prev, mem_new = controller.begin_iteration(0)
    mem_new[...] = 5.0

    class Diverged:
        diverged = True

    controller.end_iteration(Diverged())
    np.testing.assert_array_equal(controller.learned_state()["u"], before)


@pytest.mark.parametrize("field, value, says", [
    ("r", 0.0, "no-ilc.r must be a finite number > 0"),
    ("q_force", -1.0, "no-ilc.q_force must be a finite weight >= 0"),
    ("knot_spacing", 0.0, "no-ilc.knot_spacing must be a time > 0 s"),
    ("q_cutoff", -5.0, "no-ilc.q_cutoff must be a frequency >= 0 Hz"),
    ("k", (10.0, float("nan")), "no-ilc.k must be finite"),
])
def test_bad_gains_are_one_line(field, value, says):
    with pytest.raises(ValueError) as caught:
        NOILCGains(**{field: value})
    assert str(caught.value).startswith(says) and "\n" not in str(caught.value), str(caught.value)


def test_both_weights_zero_is_refused():
    with pytest.raises(ValueError, match="^no-ilc.q_position and q_force are both 0"):
        NOILCGains(q_position=0.0, q_force=0.0)


def test_a_knot_spacing_finer_than_the_sample_time_is_refused():
    with pytest.raises(ValueError, match=r"^no-ilc.knot_spacing \(5e-05 s\) must be at least the control sample"):
        _controller(np.eye(22, 12), knot_spacing=5e-5)


def test_the_lifted_model_predicts_the_nominal_closed_loop():
    """G of ilcforce.theory.norm_optimal (finite differences of the simulated nominal loop) predicts the measured
    error the simulator gives for a feed-forward it was not built from: e(u) ~ e(0) - G dc. The loop is
    nonlinear (kinematics, the implicit acceleration scheme), so the prediction holds to first order only: the
    remainder of a step of 0.05 N per knot is asked to be below 2% of the change it predicts."""
    from ilcforce.config_load import load_config
    from ilcforce.experiment import make_controller
    from ilcforce.noise import draw_iteration
    from ilcforce.simulate import IterationInputs, run_iteration

    config = load_config(None, {"reference.duration": 0.05, "noise.scale": 0.0, "no-ilc.knot_spacing": 0.01})
    controller = make_controller(config, "no-ilc")
    model = controller._lifted_model(controller)
    assert model.shape == (2 * config.n_log, 2 * 6)
    inputs = IterationInputs(0, config.plant.nominal(), config.plant.nominal(), config.wall,
                             config.reference_samples(), config.simulation, config.noise,
                             draw_iteration(0, 0, config.n_control, config.noise), config.surface.selection)

    def measured(coefficients):
        mem_prev = np.zeros((config.n_control, 4))
        mem_prev[:, :2] = controller.feedforward(coefficients)
        mem_new = np.zeros_like(mem_prev)
        record = run_iteration(inputs, controller, mem_prev, mem_new)
        assert record.status == STATUS_COMPLETE
        return controller.error_vector(mem_new)

    dc = 0.05 * np.random.default_rng(5).choice([-1.0, 1.0], 12)
    predicted = -model @ dc
    actual = measured(dc) - measured(np.zeros(12))
    remainder = np.linalg.norm(actual - predicted) / np.linalg.norm(predicted)
    assert remainder < 0.02, f"G predicts the error change to {remainder:.1%} only"


def test_the_gains_section_round_trips_through_a_config():
    from ilcforce.config_load import load_config

    config = load_config(None, {"no-ilc.r": 0.5, "no-ilc.knot_spacing": 0.05})
    assert config.gains["no-ilc"] == dataclasses.replace(NOILCGains(), r=0.5, knot_spacing=0.05)
