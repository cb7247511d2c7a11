"""The controller contract (run over the whole registry) and each law against a readable reference."""

from __future__ import annotations

import numpy as np
import pytest

from ilcforce.config import default_config
from ilcforce.controllers import REGISTRY, Controller
from ilcforce.controllers.base import (DIAG_WIDTH, LAW_SIGNATURE, MEAS_ACCEL, MEAS_FORCE_ACCEL,
                                       MEAS_WIDTH)
from ilcforce.experiment import make_controller
from ilcforce.plant import FiveBar

N = 50  # control samples of the toy memory


def _random_measurement(rng, config, k_accel=None):
    """A physically consistent measurement vector at a random pose near the task (nominal model)."""
    robot = FiveBar(config.plant.links())
    pos = np.array([rng.uniform(0.05, 0.35), rng.uniform(0.40, 0.43)])
    theta = robot.inverse_kinematics(pos)
    dtheta = rng.normal(0.0, 0.5, 2)
    J = robot.jacobian(theta)
    meas = np.zeros(MEAS_WIDTH)
    meas[0:2] = theta
    meas[2:4] = dtheta
    meas[4:6] = [rng.normal(0, 0.01), config.wall.contact_force(pos[1])]
    meas[6:8] = pos
    meas[8:10] = J @ dtheta
    meas[10:14] = J.ravel()
    meas[14:16] = rng.normal(0, 1.0, 2)
    meas[16:18] = [0.0, config.wall.stiffness * meas[9]]
    meas[18:20] = [0.0, config.wall.stiffness * meas[15]]
    D = robot.task_inertia(theta)
    C = robot.task_coriolis(theta, dtheta)
    meas[20:23] = [D[0, 0], D[0, 1], D[1, 1]]
    meas[23:27] = C.ravel()
    return meas


def _reference(rng):
    return np.ascontiguousarray(rng.normal(0.0, 1.0, (N, 12)))


@pytest.fixture(params=sorted(REGISTRY))
def method(request):
    return request.param


def test_contract(method):
    """Every registered controller follows the one contract."""
    config = default_config()
    controller = make_controller(config, method)
    assert isinstance(controller, Controller)
    assert controller.name == method
    assert controller.law.signatures, "law must be compiled with LAW_SIGNATURE"
    assert controller.law.nopython_signatures[0].args == LAW_SIGNATURE.args
    gains = controller.gains()
    assert gains.dtype == np.float64 and gains.ndim == 1
    mem_prev, mem_new = controller.begin_iteration(0)
    assert mem_prev.shape[0] == config.n_control and mem_prev.shape == mem_new.shape
    assert np.all(mem_prev == 0.0), "memory starts at zero (Theta_hat_-1 = 0, alpha_hat_-1 = 0, v_-1 = 0)"
    state = controller.learned_state()
    units = controller.learned_units()
    assert set(state) == set(units)
    for key, value in state.items():
        assert value.shape[0] == config.n_control, key


def test_law_is_pure_unless_writing(method):
    rng = np.random.default_rng(1)
    config = default_config()
    controller = make_controller(config, method)
    width = max((stop for _a, stop, _u in controller.memory_layout.values()), default=0)
    mem_prev = rng.normal(0, 1, (N, width))
    mem_new = np.full((N, width), 7.0)
    ref = _reference(rng)
    meas = _random_measurement(rng, config)
    diag = np.zeros(DIAG_WIDTH)
    before = mem_prev.copy()
    tau = controller.law(3, 0.0003, meas, ref, controller.gains(), mem_prev, mem_new, False, diag)
    assert np.all(np.isfinite(tau))
    np.testing.assert_array_equal(mem_new, 7.0, err_msg="write=False must not touch mem_new")
    tau_w = controller.law(3, 0.0003, meas, ref, controller.gains(), mem_prev, mem_new, True, diag)
    assert tau_w == tau, "writing must not change the torque"
    np.testing.assert_array_equal(mem_prev, before, err_msg="the law must never modify mem_prev")
    if width:
        assert not np.any(mem_new[3] == 7.0), "write=True must store this sample's memory"
        np.testing.assert_array_equal(np.delete(mem_new, 3, axis=0), 7.0, err_msg="only sample k is written")


def test_law_is_at_most_quadratic_in_acceleration(method):
    """The implicit scheme relies on tau(a) being a polynomial of degree <= 2 (see simulate.py).

    Third finite differences of a quadratic vanish up to roundoff: with torques of order 10 N m and
    a step of 0.7 m/s^2 the roundoff is ~1e-13; 1e-9 N m is a generous but still decisive bound.
    """
    rng = np.random.default_rng(2)
    config = default_config()
    controller = make_controller(config, method)
    width = max((stop for _a, stop, _u in controller.memory_layout.values()), default=0)
    for trial in range(5):
        mem_prev = rng.normal(0, 1, (N, width))
        mem_new = np.zeros((N, width))
        meas = _random_measurement(rng, config)
        ref = _reference(rng)
        taus = []
        for a in np.arange(-2, 3) * 0.7:
            meas[MEAS_ACCEL + 1] = a
            meas[MEAS_FORCE_ACCEL + 1] = config.wall.stiffness * a
            taus.append(controller.law(5, 0.0, meas, ref, controller.gains(), mem_prev, mem_new, False,
                                       np.zeros(DIAG_WIDTH)))
        taus = np.array(taus)
        third = np.diff(taus, n=3, axis=0)
        np.testing.assert_allclose(third, 0.0, atol=1e-9, err_msg=f"{method} law is not quadratic in a (trial {trial})")


# ---------------------------------------------------------------------------------------------
# slow, readable references written from the paper's equations with explicit matrices
# ---------------------------------------------------------------------------------------------

def _reference_surface(meas, ref_row, config, psi_desired=False):
    S = np.diag(config.surface.selection)
    Sbar = np.eye(2) - S
    lam_p, lam_f1, lam_f2 = (np.diag(getattr(config.surface, n)) for n in ("lambda_p", "lambda_f1", "lambda_f2"))
    P, dP, ddP = meas[6:8], meas[8:10], meas[14:16]
    F, dF, ddF = meas[4:6], meas[16:18], meas[18:20]
    Pd, dPd, ddPd = ref_row[0:2], ref_row[2:4], ref_row[4:6]
    Fd, dFd, ddFd = ref_row[6:8], ref_row[8:10], ref_row[10:12]
    e_p, de_p = Sbar @ (Pd - P), Sbar @ (dPd - dP)  # eq. (6)
    e_f, de_f, dde_f = S @ (Fd - F), S @ (dFd - dF), S @ (ddFd - ddF)  # eq. (7)
    sigma = lam_p @ e_p + de_p + lam_f1 @ e_f + lam_f2 @ de_f  # eq. (8)
    acc = ddPd if psi_desired else ddP
    psi = np.concatenate([lam_p @ de_p + lam_f1 @ de_f + lam_f2 @ dde_f + Sbar @ ddPd + S @ acc, dP + sigma])  # eq. (12)
    return sigma, psi


def _law_inputs(seed, width):
    rng = np.random.default_rng(seed)
    config = default_config()
    meas = _random_measurement(rng, config)
    ref = _reference(rng)
    mem_prev = rng.normal(0, 1, (N, width))
    return config, meas, ref, mem_prev


@pytest.mark.parametrize("seed", range(5))
def test_c1_matches_eq26(seed):
    config, meas, ref, _ = _law_inputs(seed, 0)
    controller = make_controller(config, "c1")
    g = config.gains["c1"]
    sigma, psi = _reference_surface(meas, ref[4], config)
    D = np.array([[meas[20], meas[21]], [meas[21], meas[22]]])
    C = meas[23:27].reshape(2, 2)
    Xi = np.vstack([D.T, C.T])  # Xi = [D C]^T, (4, 2); Xi^T Psi = D psi1 + C psi2
    J = meas[10:14].reshape(2, 2)
    u = np.diag(g.k) @ sigma + g.alpha * np.sign(sigma) + Xi.T @ psi + meas[4:6]  # eq. (26), +F (erratum 1)
    tau = controller.law(4, 0.0, meas, ref, controller.gains(), np.zeros((N, 0)), np.zeros((N, 0)), True,
                         np.zeros(DIAG_WIDTH))
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-12, atol=1e-14, err_msg="C1 law differs from eq. (26)")


@pytest.mark.parametrize("seed", range(5))
def test_c2_matches_eq27(seed):
    config, meas, ref, mem_prev = _law_inputs(seed, 2)
    controller = make_controller(config, "c2")
    g = config.gains["c2"]
    sigma, _ = _reference_surface(meas, ref[4], config)
    J = meas[10:14].reshape(2, 2)
    v = mem_prev[4] + J.T @ np.diag(g.k) @ sigma  # eq. (27)
    mem_new = np.zeros((N, 2))
    tau = controller.law(4, 0.0, meas, ref, controller.gains(), mem_prev, mem_new, True, np.zeros(DIAG_WIDTH))
    np.testing.assert_allclose(tau, v + J.T @ meas[4:6], rtol=1e-12, atol=1e-14, err_msg="C2 torque differs from eq. (27)")
    np.testing.assert_allclose(mem_new[4], v, rtol=1e-12, atol=1e-14, err_msg="C2 memory differs from eq. (27)")


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("psi_acceleration", ["measured", "desired"])
def test_c3_matches_eq14(seed, psi_acceleration):
    config, meas, ref, mem_prev = _law_inputs(seed, 9)
    from dataclasses import replace
    gains3 = replace(config.gains["c3"], psi_acceleration=psi_acceleration)
    config = replace(config, gains={**config.gains, "c3": gains3})
    controller = make_controller(config, "c3")
    sigma, psi = _reference_surface(meas, ref[4], config, psi_desired=psi_acceleration == "desired")
    Phi = np.zeros((8, 2))  # eq. (13): blockdiag(Psi, Psi)
    Phi[0:4, 0] = psi
    Phi[4:8, 1] = psi
    Gamma = np.diag(gains3.gamma)
    theta = mem_prev[4, :8] + Gamma @ Phi @ sigma  # eq. (14)
    alpha = mem_prev[4, 8] + gains3.eta * sigma @ np.sign(sigma)  # eq. (14)
    J = meas[10:14].reshape(2, 2)
    u = np.diag(gains3.k) @ sigma + Phi.T @ theta + meas[4:6] + alpha * np.sign(sigma)  # eq. (14), +F
    mem_new = np.zeros((N, 9))
    tau = controller.law(4, 0.0, meas, ref, controller.gains(), mem_prev, mem_new, True, np.zeros(DIAG_WIDTH))
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-11, atol=1e-13, err_msg="C3 torque differs from eq. (14)")
    np.testing.assert_allclose(mem_new[4, :8], theta, rtol=1e-12, err_msg="Theta_hat update differs from eq. (14)")
    assert mem_new[4, 8] == pytest.approx(alpha, rel=1e-12)


def test_theta_regressor_identity():
    """Erratum 3: with Theta = [D11 D12 C11 C12 D21 D22 C21 C22], Phi^T Theta = D psi1 + C (dP + sigma)."""
    rng = np.random.default_rng(3)
    D = rng.normal(size=(2, 2))
    C = rng.normal(size=(2, 2))
    psi = rng.normal(size=4)
    theta = np.array([D[0, 0], D[0, 1], C[0, 0], C[0, 1], D[1, 0], D[1, 1], C[1, 0], C[1, 1]])
    Phi = np.zeros((8, 2))
    Phi[0:4, 0] = psi
    Phi[4:8, 1] = psi
    np.testing.assert_allclose(Phi.T @ theta, D @ psi[:2] + C @ psi[2:], rtol=1e-14)


def test_memory_round_trip(method):
    config = default_config()
    controller = make_controller(config, method)
    rng = np.random.default_rng(4)
    stored = {key: rng.normal(size=value.shape) for key, value in controller.learned_state().items()}
    controller.restore(stored)
    for key, value in controller.learned_state().items():
        np.testing.assert_array_equal(value, stored[key], err_msg=f"{method} memory {key} not restored exactly")
