"""C2-robust and C3-robust (ilcforce.controllers.c2_robust / c3_robust): their plain laws when the tools
are off, the learning window and the Q filter doing what docs/model.md#long-run says, and one line for
bad options. That they stay bounded over 1,000 iterations is measured by the long-run study (make long)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ilcforce.config import ConfigError
from ilcforce.config_load import load_config
from ilcforce.experiment import make_controller

from test_controllers import FORCE, JACOBIAN, N, _law, _law_inputs, _reference_surface


def _off(config, method, **more):
    gains = replace(config.gains[method], learn_from=0.0, q_cutoff=0.0, **more)
    return replace(config, gains={**config.gains, method: gains})


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("robust, plain, width", [("c3-robust", "c3", 9), ("c2-robust", "c2", 2)])
def test_with_the_tools_off_each_robust_law_is_its_plain_law_bit_for_bit(seed, robust, plain, width):
    config, meas, ref, mem_prev = _law_inputs(seed, width)
    extra = {"alpha_max": np.inf, "psi_acceleration": "measured"} if robust == "c3-robust" else {}
    config = _off(config, robust, **extra)
    a, b = make_controller(config, robust), make_controller(config, plain)
    mem_a, mem_b = np.zeros((N, width)), np.zeros((N, width))
    for t in (0.0, 0.5):
        ta = _law(a, 4, t, meas, ref, mem_prev, mem_a, True)
        tb = _law(b, 4, t, meas, ref, mem_prev, mem_b, True)
        np.testing.assert_array_equal(ta, tb)
        np.testing.assert_array_equal(mem_a, mem_b)


@pytest.mark.parametrize("seed", range(3))
def test_before_the_learning_window_c3_robust_keeps_its_memory_and_acts_on_it_as_c3(seed):
    """t < t_L: Theta_hat and alpha_hat are carried unchanged; the torque is eq. (14) with that memory."""
    config, meas, ref, mem_prev = _law_inputs(seed, 9)
    mem_prev[:, 8] = np.abs(mem_prev[:, 8]) * 0.01  # alpha_hat below its bound
    g = replace(config.gains["c3-robust"], psi_acceleration="measured")
    config = replace(config, gains={**config.gains, "c3-robust": g})
    controller = make_controller(config, "c3-robust")
    mem_new = np.zeros((N, 9))
    tau = _law(controller, 4, 0.5 * g.learn_from, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_array_equal(mem_new[4], mem_prev[4])
    sigma, psi = _reference_surface(meas, ref[4], config)
    Phi = np.zeros((8, 2))
    Phi[0:4, 0], Phi[4:8, 1] = psi, psi
    u = np.diag(g.k) @ sigma + Phi.T @ mem_prev[4, :8] + meas[FORCE:FORCE + 2] + mem_prev[4, 8] * np.sign(sigma)
    np.testing.assert_allclose(tau, meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2).T @ u, rtol=1e-11, atol=1e-13)
    # after t_L it learns as eq. (14), alpha_hat capped at alpha_max
    mem_prev[4, 8] = 1.0
    _law(controller, 4, 2.0 * g.learn_from, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_allclose(mem_new[4, :8], mem_prev[4, :8] + np.diag(g.gamma) @ Phi @ sigma, rtol=1e-12)
    assert mem_new[4, 8] == g.alpha_max


def test_before_the_learning_window_c2_robust_feeds_back_what_it_does_not_learn():
    """t < t_L: v is carried unchanged and J^T k sigma still acts, as feedback: the torque is C2's."""
    config, meas, ref, mem_prev = _law_inputs(0, 2)
    config = replace(config, gains={**config.gains, "c2-robust": replace(config.gains["c2-robust"], q_cutoff=0.0)})
    robust, plain = make_controller(config, "c2-robust"), make_controller(config, "c2")
    mem_a, mem_b = np.zeros((N, 2)), np.zeros((N, 2))
    ta = _law(robust, 4, 0.001, meas, ref, mem_prev, mem_a, True)
    tb = _law(plain, 4, 0.001, meas, ref, mem_prev, mem_b, True)
    np.testing.assert_allclose(ta, tb, rtol=1e-12)
    np.testing.assert_array_equal(mem_a[4], mem_prev[4])
    assert not np.array_equal(mem_b[4], mem_prev[4]), "C2 itself learns there"


@pytest.mark.parametrize("method", ["c2-robust", "c3-robust"])
def test_the_memory_an_iteration_hands_on_is_the_q_filtered_one(method):
    """What an iteration wrote (a 0.5 Hz task component plus 1 kHz content) is handed to the next iteration
    through Q: scipy's zero-phase Butterworth of the stated order and cutoff, C-contiguous for the compiled
    loop; the task component passes and the 1 kHz content is gone. A diverged iteration hands on nothing."""
    from types import SimpleNamespace

    from scipy.signal import butter, sosfiltfilt

    config = load_config(None)
    g, ts = config.gains[method], config.simulation.sample_time
    controller = make_controller(config, method)
    n = controller.n_control
    t = np.arange(n) * ts
    task, noise = np.sin(2 * np.pi * 0.5 * t), 0.1 * np.sin(2 * np.pi * 1000.0 * t)
    _prev, new = controller.begin_iteration(0)
    new[...] = (task + noise)[:, None]
    written = new.copy()
    controller.end_iteration(SimpleNamespace(diverged=False))
    handed, _ = controller.begin_iteration(1)
    sos = butter(g.q_order, g.q_cutoff, fs=1.0 / ts, output="sos")
    np.testing.assert_array_equal(handed, sosfiltfilt(sos, written, axis=0))
    assert handed.flags["C_CONTIGUOUS"]
    middle = slice(n // 10, -n // 10)  # away from the ends, where any filter's padding shows
    np.testing.assert_allclose(handed[middle, 0], task[middle], atol=1e-3)
    _prev, new = controller.begin_iteration(1)
    new[...] = 7.0
    controller.end_iteration(SimpleNamespace(diverged=True))
    again, _ = controller.begin_iteration(2)
    np.testing.assert_array_equal(again, handed)


@pytest.mark.parametrize("key, value, words", [
    ("c3-robust.learn_from", -0.01, "c3-robust.learn_from must be a finite time >= 0 s"),
    ("c2-robust.q_cutoff", -1.0, "c2-robust.q_cutoff must be a frequency >= 0 Hz"),
    ("c2-robust.q_order", 0, "c2-robust.q_order must be an integer 1..8"),
    ("c3-robust.alpha_max", -1.0, "c3-robust.alpha_max must be >= 0"),
])
def test_bad_options_are_one_line_naming_the_key(key, value, words):
    with pytest.raises(ConfigError, match=words.replace(".", r"\.")) as info:
        load_config(None, {key: value})
    assert "\n" not in str(info.value)


def test_a_q_cutoff_above_nyquist_is_refused_with_the_numbers():
    config = load_config(None, {"c2-robust.q_cutoff": 6000.0})
    with pytest.raises(ValueError, match=r"c2-robust\.q_cutoff \(6000 Hz\) must be below the Nyquist frequency 5000 Hz"):
        make_controller(config, "c2-robust")


def test_c3_robust_decides_its_own_psi_acceleration():
    """[c3]'s psi_acceleration does not reach C3-robust (its own choice, docs/model.md#long-run); its
    other keys do (the family rule), and its own table still sets it."""
    config = load_config(None, {"c3.psi_acceleration": "measured", "c3.eta": 2.0})
    assert config.gains["c3-robust"].psi_acceleration == "desired" and config.gains["c3-robust"].eta == 2.0
    own = load_config(None, {"c3-robust.psi_acceleration": "measured"})
    assert own.gains["c3-robust"].psi_acceleration == "measured"


# --- the leak of alpha_hat (c3-robust.alpha_leak, alpha_nominal): learned and bounded without a cap ---------


def _leaky(config, **gains):
    g = replace(config.gains["c3-robust"], **gains)
    return replace(config, gains={**config.gains, "c3-robust": g}), g


def test_alpha_hat_is_not_leaked_by_default():
    """The shipped C3-robust has no leak, so its runs and every stored number are today's."""
    g = load_config(None).gains["c3-robust"]
    assert (g.alpha_leak, g.alpha_nominal) == (0.0, 0.0)


@pytest.mark.parametrize("seed", range(3))
def test_alpha_leak_pulls_alpha_hat_towards_its_nominal_value_before_the_eq14_update(seed):
    """alpha_hat_j = min(alpha_max, alpha_hat_{j-1} - alpha_leak (alpha_hat_{j-1} - alpha_nominal) + eta |sigma|_1);
    Theta_hat's update and the law's other terms are C3-robust's without the leak."""
    config, meas, ref, mem_prev = _law_inputs(seed, 9)
    config, g = _leaky(config, psi_acceleration="measured", alpha_max=1e12, alpha_leak=0.25, alpha_nominal=0.01)
    plain_config, _ = _leaky(config, alpha_leak=0.0)
    mem_prev[4, 8] = 0.2 + 0.1 * seed
    leaky, plain = make_controller(config, "c3-robust"), make_controller(plain_config, "c3-robust")
    t = 2.0 * g.learn_from  # inside the learning window
    mem_l, mem_p = np.zeros((N, 9)), np.zeros((N, 9))
    tau = _law(leaky, 4, t, meas, ref, mem_prev, mem_l, True)
    _law(plain, 4, t, meas, ref, mem_prev, mem_p, True)
    sigma, psi = _reference_surface(meas, ref[4], config)
    previous = mem_prev[4, 8]
    alpha = previous - 0.25 * (previous - 0.01) + g.eta * sigma @ np.sign(sigma)
    assert mem_l[4, 8] == pytest.approx(alpha, rel=1e-13)
    assert mem_p[4, 8] == pytest.approx(previous + g.eta * sigma @ np.sign(sigma), rel=1e-13)
    assert mem_l[4, 8] < mem_p[4, 8], "the leak takes off 0.25 (alpha_hat - 0.01) > 0"
    np.testing.assert_array_equal(mem_l[4, :8], mem_p[4, :8])
    Phi = np.zeros((8, 2))
    Phi[0:4, 0], Phi[4:8, 1] = psi, psi
    u = np.diag(g.k) @ sigma + Phi.T @ mem_l[4, :8] + meas[FORCE:FORCE + 2] + mem_l[4, 8] * np.sign(sigma)
    np.testing.assert_allclose(tau, meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2).T @ u, rtol=1e-11, atol=1e-13)
    # the cap still acts after the leak
    capped, _ = _leaky(config, alpha_max=0.05)
    controller = make_controller(capped, "c3-robust")
    _law(controller, 4, t, meas, ref, mem_prev, mem_l, True)
    assert mem_l[4, 8] == 0.05


def test_with_a_leak_alpha_hat_settles_at_nominal_plus_increment_over_leak():
    """Iterated with a constant eta |sigma|_1, the leaky update converges to alpha_nominal + increment /
    alpha_leak (bounded without a cap, and a function of sigma: learned); without the leak it grows by the
    increment every iteration."""
    from ilcforce.controllers.c3 import alpha_update

    leak, nominal, increment = 0.05, 0.01, 1e-3
    alpha = plain = 0.0
    for _ in range(600):
        alpha = alpha_update(alpha, increment, np.inf, leak, nominal)
        plain = alpha_update(plain, increment, np.inf, 0.0, nominal)
    assert alpha == pytest.approx(nominal + increment / leak, rel=1e-9)
    assert plain == pytest.approx(600 * increment, rel=1e-12)


def _run_keeping_alpha(config, iterations=3):
    """A run of C3-robust through the simulation loop, with alpha_hat as each iteration handed it on."""
    from ilcforce import simulate
    from ilcforce.experiment import iteration_inputs

    reference = config.reference_samples()
    controller = make_controller(config, "c3-robust")
    out = []
    for j in range(iterations):
        mem_prev, mem_new = controller.begin_iteration(j)
        record = simulate.run_iteration(iteration_inputs(config, j, reference), controller, mem_prev, mem_new)
        controller.end_iteration(record)
        out.append((record, controller.learned_state()["alpha_hat"].copy()))
    return out


def test_the_simulation_loop_leaks_alpha_hat():
    """The law carries the leak through the simulation loop: on the five-bar, 3 iterations of C3-robust with a
    leak complete and hand on an alpha_hat pulled towards alpha_nominal = 0.02 N (unleaked: up to 0.018 N)."""
    config, _g = _leaky(load_config(None), alpha_leak=0.3, alpha_nominal=0.02, alpha_max=1e12)
    leaky = _run_keeping_alpha(config)
    plain = _run_keeping_alpha(_leaky(config, alpha_leak=0.0)[0])
    assert all(record.status == "complete" for record, _alpha in leaky + plain)
    assert np.max(np.abs(leaky[-1][1] - plain[-1][1])) > 1e-3
    assert np.mean(np.abs(leaky[-1][1] - 0.02)) < np.mean(np.abs(plain[-1][1] - 0.02))


@pytest.mark.parametrize("key, value, words", [
    ("c3-robust.alpha_leak", 1.0, "c3-robust.alpha_leak must be in [0, 1)"),
    ("c3-robust.alpha_leak", -0.1, "c3-robust.alpha_leak must be in [0, 1)"),
    ("c3-robust.alpha_nominal", -0.01, "c3-robust.alpha_nominal must be a finite gain >= 0 N"),
])
def test_bad_leak_options_are_one_line_naming_the_key(key, value, words):
    with pytest.raises(ConfigError, match=words.replace(".", r"\.").replace("[", r"\[").replace(")", r"\)")) as info:
        load_config(None, {key: value})
    assert "\n" not in str(info.value)
