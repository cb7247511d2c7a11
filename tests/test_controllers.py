"""The controller contract (run over the whole registry) and each law against a readable reference."""

from __future__ import annotations

import numpy as np
import pytest

from ilcforce.config_load import default_config
from ilcforce.controllers import REGISTRY, Controller
from ilcforce.controllers.nd import (
    M_ACCEL, M_DTHETA, M_FORCE, M_FORCE_ACCEL, M_FORCE_RATE, M_JACOBIAN, M_POSITION, M_TASK_CORIOLIS, M_TASK_GRAVITY,
    M_TASK_INERTIA, M_THETA, M_VELOCITY, M_WIDTH, at_py, diag_width, law_signature,
)
from ilcforce.experiment import make_controller
from ilcforce.plants import MODELS, make_plant, plant_class

N = 50  # control samples of the toy memory
AXES = 2  # the planar robots' task: the one law with n = 2


def _at(offset) -> int:
    """Where a measurement block starts for the planar task (``ilcforce.controllers.nd``'s layout at n = 2)."""
    return at_py(offset, AXES)


THETA, DTHETA, FORCE, POSITION, VELOCITY = (_at(o) for o in (M_THETA, M_DTHETA, M_FORCE, M_POSITION, M_VELOCITY))
JACOBIAN, ACCEL, FORCE_RATE, FORCE_ACCEL = (_at(o) for o in (M_JACOBIAN, M_ACCEL, M_FORCE_RATE, M_FORCE_ACCEL))
INERTIA, CORIOLIS, GRAVITY = (_at(o) for o in (M_TASK_INERTIA, M_TASK_CORIOLIS, M_TASK_GRAVITY))


def _law(controller, k, t, meas, ref, mem_prev, mem_new, write, diag=None) -> np.ndarray:
    """The controller's compiled law at sample k: the joint torque (AXES,)."""
    tau = np.full(AXES, np.nan)
    if diag is None:
        diag = np.zeros(diag_width(AXES) + getattr(controller, "nd_scratch", 0))
    assert controller.law(k, t, meas, ref, controller.gains(), mem_prev, mem_new, write, diag, tau) == 0
    return tau


def _random_measurement(rng, config, k_accel=None):
    """A physically consistent measurement vector at a random pose near the task (nominal model)."""
    robot = make_plant(config.plant.nominal())
    pos = np.array([rng.uniform(0.05, 0.35), rng.uniform(0.40, 0.43)])
    theta = robot.inverse_kinematics(pos)
    dtheta = rng.normal(0.0, 0.5, 2)
    J = robot.jacobian(theta)
    meas = np.zeros(_at(M_WIDTH))
    meas[THETA:THETA + 2] = theta
    meas[DTHETA:DTHETA + 2] = dtheta
    meas[FORCE:FORCE + 2] = [rng.normal(0, 0.01), config.wall.contact_force(pos[1])]
    meas[POSITION:POSITION + 2] = pos
    meas[VELOCITY:VELOCITY + 2] = J @ dtheta
    meas[JACOBIAN:JACOBIAN + 4] = J.ravel()
    meas[ACCEL:ACCEL + 2] = rng.normal(0, 1.0, 2)
    meas[FORCE_RATE:FORCE_RATE + 2] = [0.0, config.wall.stiffness * meas[VELOCITY + 1]]
    meas[FORCE_ACCEL:FORCE_ACCEL + 2] = [0.0, config.wall.stiffness * meas[ACCEL + 1]]
    meas[INERTIA:INERTIA + 4] = robot.task_inertia(theta).ravel()
    meas[CORIOLIS:CORIOLIS + 4] = robot.task_coriolis(theta, dtheta).ravel()
    meas[GRAVITY:GRAVITY + 2] = robot.task_gravity(theta)  # zero for the five-bar
    return meas


def _reference(rng):
    return np.ascontiguousarray(rng.normal(0.0, 1.0, (N, 6 * AXES)))


@pytest.fixture(params=sorted(REGISTRY))
def method(request):
    return request.param


@pytest.fixture(params=sorted(m for m in MODELS if plant_class(m).dimension == 2))
def plant(request):
    """Every registered 2-joint plant model: the contract holds for every method on every such robot (on the
    spatial arm: tests/test_ndof.py)."""
    return request.param


def test_contract(method, plant, plant_config):
    """Every registered controller follows the one contract."""
    config = plant_config(plant)
    controller = make_controller(config, method)
    assert isinstance(controller, Controller)
    assert controller.name == method
    assert controller.law.signatures, "law must be compiled with the contract's signature"
    assert controller.law.nopython_signatures[0].args == law_signature().args
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


def test_law_is_pure_unless_writing(method, plant, plant_config):
    rng = np.random.default_rng(1)
    config = plant_config(plant)
    controller = make_controller(config, method)
    width = max((stop for _a, stop, _u in controller.memory_layout.values()), default=0)
    mem_prev = rng.normal(0, 1, (N, width))
    mem_new = np.full((N, width), 7.0)
    ref = _reference(rng)
    meas = _random_measurement(rng, config)
    diag = np.zeros(diag_width(AXES) + getattr(controller, "nd_scratch", 0))
    before = mem_prev.copy()
    tau = _law(controller, 3, 0.0003, meas, ref, mem_prev, mem_new, False, diag)
    assert np.all(np.isfinite(tau))
    np.testing.assert_array_equal(mem_new, 7.0, err_msg="write=False must not touch mem_new")
    tau_w = _law(controller, 3, 0.0003, meas, ref, mem_prev, mem_new, True, diag)
    np.testing.assert_array_equal(tau_w, tau, err_msg="writing must not change the torque")
    np.testing.assert_array_equal(mem_prev, before, err_msg="the law must never modify mem_prev")
    if width:
        assert not np.any(mem_new[3] == 7.0), "write=True must store this sample's memory"
        np.testing.assert_array_equal(np.delete(mem_new, 3, axis=0), 7.0, err_msg="only sample k is written")


def test_law_is_at_most_quadratic_in_acceleration(method, plant, plant_config):
    """The implicit scheme relies on tau(a) being a polynomial of degree <= 2 (see simulate.py).

    Third finite differences of a quadratic vanish up to roundoff: with torques of order 10 N m and
    a step of 0.7 m/s^2 the roundoff is ~1e-13; 1e-9 N m is a generous but still decisive bound.
    """
    rng = np.random.default_rng(2)
    config = plant_config(plant)
    controller = make_controller(config, method)
    width = max((stop for _a, stop, _u in controller.memory_layout.values()), default=0)
    for trial in range(5):
        mem_prev = rng.normal(0, 1, (N, width))
        mem_new = np.zeros((N, width))
        meas = _random_measurement(rng, config)
        ref = _reference(rng)
        taus = []
        for a in np.arange(-2, 3) * 0.7:
            meas[ACCEL + 1] = a
            meas[FORCE_ACCEL + 1] = config.wall.stiffness * a
            taus.append(_law(controller, 5, 0.0, meas, ref, mem_prev, mem_new, False))
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
    P, dP, ddP = meas[POSITION:POSITION + 2], meas[VELOCITY:VELOCITY + 2], meas[ACCEL:ACCEL + 2]
    F, dF, ddF = meas[FORCE:FORCE + 2], meas[FORCE_RATE:FORCE_RATE + 2], meas[FORCE_ACCEL:FORCE_ACCEL + 2]
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
    D = meas[INERTIA:INERTIA + 4].reshape(2, 2)
    C = meas[CORIOLIS:CORIOLIS + 4].reshape(2, 2)
    Xi = np.vstack([D.T, C.T])  # Xi = [D C]^T, (4, 2); Xi^T Psi = D psi1 + C psi2
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    u = np.diag(g.k) @ sigma + g.alpha * np.sign(sigma) + Xi.T @ psi + meas[FORCE:FORCE + 2]  # eq. (26), +F (erratum 1)
    tau = _law(controller, 4, 0.0, meas, ref, np.zeros((N, 0)), np.zeros((N, 0)), True)
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-12, atol=1e-14, err_msg="C1 law differs from eq. (26)")


@pytest.mark.parametrize("seed", range(5))
def test_c2_matches_eq27(seed):
    config, meas, ref, mem_prev = _law_inputs(seed, 2)
    controller = make_controller(config, "c2")
    g = config.gains["c2"]
    sigma, _ = _reference_surface(meas, ref[4], config)
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    v = mem_prev[4] + J.T @ np.diag(g.k) @ sigma  # eq. (27)
    mem_new = np.zeros((N, 2))
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_allclose(tau, v + J.T @ meas[FORCE:FORCE + 2], rtol=1e-12, atol=1e-14, err_msg="C2 torque differs from eq. (27)")
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
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    u = np.diag(gains3.k) @ sigma + Phi.T @ theta + meas[FORCE:FORCE + 2] + alpha * np.sign(sigma)  # eq. (14), +F
    mem_new = np.zeros((N, 9))
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
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


def test_memory_round_trip(method, plant, plant_config):
    config = plant_config(plant)
    controller = make_controller(config, method)
    rng = np.random.default_rng(4)
    stored = {key: rng.normal(size=value.shape) for key, value in controller.learned_state().items()}
    controller.restore(stored)
    for key, value in controller.learned_state().items():
        np.testing.assert_array_equal(value, stored[key], err_msg=f"{method} memory {key} not restored exactly")


# ---------------------------------------------------------------------------------------------
# the methods beyond the paper, each against its own readable reference
# ---------------------------------------------------------------------------------------------

def _task_model(meas):
    D = meas[INERTIA:INERTIA + 4].reshape(2, 2)
    C = meas[CORIOLIS:CORIOLIS + 4].reshape(2, 2)
    return D, C


@pytest.mark.parametrize("seed", range(5))
def test_smc_bl_matches_eq26_with_a_boundary_layer(seed):
    """sat(sigma / phi) for sgn(sigma) (Slotine & Li 1991, eq. 7.30); everything else is eq. (26)."""
    config, meas, ref, _ = _law_inputs(seed, 0)
    controller = make_controller(config, "smc-bl")
    g = config.gains["smc-bl"]
    sigma, psi = _reference_surface(meas, ref[4], config)
    D, C = _task_model(meas)
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    sat = np.clip(sigma / np.array(g.phi), -1.0, 1.0)
    u = np.diag(g.k) @ sigma + g.alpha * sat + D @ psi[:2] + C @ psi[2:] + meas[FORCE:FORCE + 2]
    tau = _law(controller, 4, 0.0, meas, ref, np.zeros((N, 0)), np.zeros((N, 0)), True)
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-12, atol=1e-14, err_msg="SMC-BL differs from eq. (26) with sat")


def test_smc_bl_is_c1_outside_its_boundary_layer():
    """With phi far below |sigma|, sat(sigma / phi) = sgn(sigma): the torque is C1's, bit for bit."""
    from dataclasses import replace

    config, meas, ref, _ = _law_inputs(0, 0)
    sigma, _ = _reference_surface(meas, ref[4], config)
    assert np.all(np.abs(sigma) > 1e-12), "the random state must be off the surface"
    bl = replace(config.gains["smc-bl"], k=config.gains["c1"].k, alpha=config.gains["c1"].alpha, phi=(1e-300, 1e-300))
    config = replace(config, gains={**config.gains, "smc-bl": bl})
    args = (4, 0.0, meas, ref)
    tail = (np.zeros((N, 0)), np.zeros((N, 0)), False)
    c1 = make_controller(config, "c1")
    blc = make_controller(config, "smc-bl")
    np.testing.assert_array_equal(_law(blc, *args, *tail), _law(c1, *args, *tail))


@pytest.mark.parametrize("seed", range(5))
def test_c3_leak_matches_eq14_with_leakage_and_bound(seed):
    """Theta_hat_j = (1 - lambda) Theta_hat_{j-1} + Gamma Phi sigma; alpha_hat_j capped at alpha_max."""
    from dataclasses import replace

    config, meas, ref, mem_prev = _law_inputs(seed, 9)
    mem_prev[4, 8] = 0.5  # above the default bound 0.1 N: the cap must act
    g = config.gains["c3-leak"]
    controller = make_controller(config, "c3-leak")
    sigma, psi = _reference_surface(meas, ref[4], config)
    Phi = np.zeros((8, 2))
    Phi[0:4, 0] = psi
    Phi[4:8, 1] = psi
    keep = 1.0 - g.leakage
    theta = keep * mem_prev[4, :8] + np.diag(g.gamma) @ Phi @ sigma
    alpha = min(g.alpha_max, keep * mem_prev[4, 8] + g.eta * sigma @ np.sign(sigma))
    assert alpha == g.alpha_max
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    u = np.diag(g.k) @ sigma + Phi.T @ theta + meas[FORCE:FORCE + 2] + alpha * np.sign(sigma)
    mem_new = np.zeros((N, 9))
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-11, atol=1e-13, err_msg="C3-leak torque")
    np.testing.assert_allclose(mem_new[4, :8], theta, rtol=1e-12, err_msg="leaky Theta_hat update")
    assert mem_new[4, 8] == alpha
    # lambda = 0 and an unreachable bound give the paper's C3 bit for bit
    off = replace(g, leakage=0.0, alpha_max=1e300)
    config = replace(config, gains={**config.gains, "c3-leak": off})
    leak, c3 = make_controller(config, "c3-leak"), make_controller(config, "c3")
    mem_a, mem_b = np.zeros((N, 9)), np.zeros((N, 9))
    ta = _law(leak, 4, 0.0, meas, ref, mem_prev, mem_a, True)
    tb = _law(c3, 4, 0.0, meas, ref, mem_prev, mem_b, True)
    np.testing.assert_array_equal(ta, tb)
    np.testing.assert_array_equal(mem_a, mem_b)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("model", sorted(m for m in MODELS if plant_class(m).dimension == 2))  # SL-adapt: 2 joints
def test_sl_adapt_is_slotine_li_with_the_plants_regressor(seed, model, plant_config):
    """tau = Y(q, dq, dq_r, ddq_r) a_hat + J^T (k sigma + F), a_hat(t_k) = a_hat(t_{k-1}) + Ts Gamma Y^T
    J^-1 sigma (Slotine & Li eqs. 9.25-9.27), written with explicit matrices: dq_r = J^-1 (dP + sigma),
    ddq_r = J^-1 (psi1 - dJ dq_r), Y from the plant's module; at k = 0 the estimate starts from the
    previous iteration's last row."""
    import importlib

    config = plant_config(model)
    rng = np.random.default_rng(seed)
    meas = _random_measurement(rng, config)
    ref = _reference(rng)
    g = config.gains["sl-adapt"]
    ts = config.simulation.sample_time
    controller = make_controller(config, "sl-adapt")
    module = importlib.import_module(MODELS[model][0])  # the registry's module (its key need not be its name)
    nominal = config.plant.nominal()
    width = len(module.base_parameters(nominal))
    sigma, psi = _reference_surface(meas, ref[4], config, psi_desired=g.psi_acceleration == "desired")
    theta, dtheta = meas[THETA:THETA + 2], meas[DTHETA:DTHETA + 2]
    robot = make_plant(nominal)
    J, dJ = robot.jacobian(theta), robot.jacobian_derivative(theta, dtheta)
    dq_r = np.linalg.solve(J, psi[2:4])
    ddq_r = np.linalg.solve(J, psi[0:2] - dJ @ dq_r)
    Y = np.array(module.regressor(nominal.as_array(), *theta, *dtheta, *dq_r, *ddq_r)).reshape(2, 6)[:, :width]
    mem_prev = rng.normal(0.0, 1.0, (N, width))
    mem_new = rng.normal(0.0, 1.0, (N, width))  # row 3: a_hat(t_3), written at the previous sample
    a_0 = g.initial_estimate * module.base_parameters(nominal)  # the memory holds a_hat - a_0
    change = mem_new[3] + ts * np.diag(g.gamma[:width]) @ Y.T @ np.linalg.solve(J, sigma)  # eq. 9.27
    tau_ref = Y @ (a_0 + change) + J.T @ (np.diag(g.k) @ sigma + meas[FORCE:FORCE + 2])  # eq. 9.25
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
    # round-off of J^-1 and of sums of N m-sized terms
    np.testing.assert_allclose(tau, tau_ref, rtol=1e-9, atol=1e-12, err_msg=f"SL-adapt torque on {model}")
    np.testing.assert_allclose(mem_new[4], change, rtol=1e-10, err_msg=f"SL-adapt a_hat update on {model}")
    # k = 0 starts from the previous iteration's last row
    mem0 = np.full((N, width), 5.0)
    _law(controller, 0, 0.0, meas, ref, mem_prev, mem0, True)
    sigma0, psi0 = _reference_surface(meas, ref[0], config, psi_desired=g.psi_acceleration == "desired")
    dq0 = np.linalg.solve(J, psi0[2:4])
    Y0 = np.array(module.regressor(nominal.as_array(), *theta, *dtheta, *dq0,
                                   *np.linalg.solve(J, psi0[0:2] - dJ @ dq0))).reshape(2, 6)[:, :width]
    np.testing.assert_allclose(mem0[0], mem_prev[-1] + ts * np.diag(g.gamma[:width]) @ Y0.T @ np.linalg.solve(J, sigma0),
                               rtol=1e-10)


def test_sl_adapt_starts_from_the_nominal_parameters_and_carries_its_estimate(plant_config):
    from ilcforce.plants import serial2r

    config = plant_config("serial2r")
    controller = make_controller(config, "sl-adapt")
    np.testing.assert_array_equal(controller.initial_estimate(),
                                  config.gains["sl-adapt"].initial_estimate * serial2r.base_parameters(config.plant.nominal()))
    assert config.gains["sl-adapt"].initial_estimate == 1.0
    assert REGISTRY["sl-adapt"].carries_memory


@pytest.mark.parametrize("seed", range(3))
def test_pd_ilc_law_is_pd_feedback_plus_last_iterations_feedforward(seed):
    """tau = v_j + J^T k sigma + J^T F; the law writes v_j + J^T L sigma for the Q filter to finish."""
    config, meas, ref, mem_prev = _law_inputs(seed, 2)
    g = config.gains["pd-ilc"]
    controller = make_controller(config, "pd-ilc")
    sigma, _ = _reference_surface(meas, ref[4], config)
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    mem_new = np.zeros((N, 2))
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_allclose(tau, mem_prev[4] + J.T @ (np.diag(g.k) @ sigma + meas[FORCE:FORCE + 2]), rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(mem_new[4], mem_prev[4] + J.T @ np.diag(g.learning) @ sigma, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("method", ["c3", "c3-leak"])
def test_c3_with_gravity_matches_eq14_with_the_full_theta(seed, method, plant_config):
    """With gravity (serial 2R), Psi = [psi1; dP + sigma; 1; 1] and Theta has 12 entries (eq. 13):
    Gamma's G block is ``gamma_gravity`` (G11 G12 for x, G21 G22 for y), read by name."""
    from dataclasses import replace

    config = plant_config("serial2r")
    assert config.plant.has_gravity
    distinct = replace(config.gains[method], gamma_gravity=(1e3, 2e3, 3e3, 4e3))  # a misplaced entry shows
    config = replace(config, gains={**config.gains, method: distinct})
    rng = np.random.default_rng(seed)
    meas = _random_measurement(rng, config)
    ref = _reference(rng)
    mem_prev = rng.normal(0, 1, (N, 13))
    g = config.gains[method]
    keep = 1.0 - getattr(g, "leakage", 0.0)
    controller = make_controller(config, method)
    sigma, psi = _reference_surface(meas, ref[4], config, psi_desired=g.psi_acceleration == "desired")
    psi = np.concatenate([psi, [1.0, 1.0]])  # eq. (12) with the G block
    Phi = np.zeros((12, 2))
    Phi[0:6, 0] = psi
    Phi[6:12, 1] = psi
    Gamma = np.diag([*g.gamma[0:4], *g.gamma_gravity[0:2], *g.gamma[4:8], *g.gamma_gravity[2:4]])
    theta = keep * mem_prev[4, :12] + Gamma @ Phi @ sigma  # eq. (14)
    alpha = min(getattr(g, "alpha_max", np.inf), keep * mem_prev[4, 12] + g.eta * sigma @ np.sign(sigma))
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    u = np.diag(g.k) @ sigma + Phi.T @ theta + meas[FORCE:FORCE + 2] + alpha * np.sign(sigma)
    mem_new = np.zeros((N, 13))
    tau = _law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True)
    np.testing.assert_allclose(tau, J.T @ u, rtol=1e-11, atol=1e-13, err_msg=f"{method} torque with the G block")
    np.testing.assert_allclose(mem_new[4, :12], theta, rtol=1e-12, err_msg=f"{method} Theta_hat with the G block")
    assert mem_new[4, 12] == pytest.approx(alpha, rel=1e-12)


@pytest.mark.parametrize("method", ["c2", "c3", "pd-ilc"])
def test_the_learned_state_handed_out_is_never_written_again(method):
    """learned_state() gives the finished iteration's own buffer (no copy): a later iteration, a
    diverged one and restore() must leave what was handed out as it was (a record waiting for the
    store holds it)."""
    from ilcforce.records import IterationRecord, STATUS_COMPLETE, STATUS_DIVERGED

    def record(status):
        return IterationRecord(0, status, float("nan"), "", 0, {})

    controller = make_controller(default_config(), method)
    rng = np.random.default_rng(3)
    _prev, new = controller.begin_iteration(0)
    new[...] = rng.normal(size=new.shape)
    controller.end_iteration(record(STATUS_COMPLETE))
    handed = controller.learned_state()
    kept = {key: value.copy() for key, value in handed.items()}
    for status in (STATUS_COMPLETE, STATUS_DIVERGED):
        _prev, new = controller.begin_iteration(1)
        assert not any(np.shares_memory(new, value) for value in handed.values())
        new[...] = rng.normal(size=new.shape)
        controller.end_iteration(record(status))
    controller.restore({key: np.zeros_like(value) for key, value in handed.items()})
    for key, value in handed.items():
        np.testing.assert_array_equal(value, kept[key], err_msg=key)
    assert all(not value.any() for value in controller.learned_state().values())


def test_the_learned_state_handed_out_cannot_be_written():
    """The views learned_state() hands out are the buffer the next iteration reads as mem_prev: a
    record's taker writing one in place would change every later iteration (a review found it)."""
    from ilcforce.records import IterationRecord, STATUS_COMPLETE

    controller = make_controller(default_config(), "c3")
    _prev, new = controller.begin_iteration(0)
    new[...] = 1.0
    controller.end_iteration(IterationRecord(0, STATUS_COMPLETE, float("nan"), "", 0, {}))
    for key, value in controller.learned_state().items():
        with pytest.raises(ValueError, match="read-only"):
            value[0] = 0.0
    mem_prev, _new = controller.begin_iteration(1)
    assert np.all(mem_prev == 1.0)


@pytest.mark.parametrize("method", ["c2", "c3", "c3-leak", "pd-ilc"])
def test_gravity_feedforward_adds_the_nominal_task_gravity(method, plant_config):
    """g_ff adds g_ff J^T G_nom (the nominal task gravity at the measured angles) to the torque and
    nothing else: same memory written; off by default, so the paper's laws are unchanged."""
    from dataclasses import replace

    config = plant_config("serial2r")
    rng = np.random.default_rng(7)
    meas = _random_measurement(rng, config)
    ref = _reference(rng)
    taus, memories = [], []
    for g_ff in (0.0, 0.75):
        gains = replace(config.gains[method], gravity_feedforward=g_ff)
        controller = make_controller(replace(config, gains={**config.gains, method: gains}), method)
        assert controller.uses_nominal_dynamics == (g_ff != 0.0)  # the simulator fills G_nom only then
        mem_prev, _ = controller.begin_iteration(0)
        mem_prev = rng.normal(0, 1, mem_prev.shape) if g_ff == 0.0 else memories[0][0]
        mem_new = np.zeros_like(mem_prev)
        taus.append(_law(controller, 4, 0.0, meas, ref, mem_prev, mem_new, True))
        memories.append((mem_prev, mem_new))
    J = meas[JACOBIAN:JACOBIAN + 4].reshape(2, 2)
    assert np.linalg.norm(meas[GRAVITY:GRAVITY + 2]) > 1.0  # the 2R arm's task gravity is N-sized
    # round-off of a sum of N m-sized terms: 1e-12 relative to the torque
    np.testing.assert_allclose(taus[1] - taus[0], J.T @ (0.75 * meas[GRAVITY:GRAVITY + 2]), rtol=1e-9, atol=1e-12 * np.abs(taus[0]).max(),
                               err_msg=f"{method}: g_ff J^T G_nom")
    np.testing.assert_array_equal(memories[0][1], memories[1][1], err_msg=f"{method}: g_ff changes no memory")
    assert default_config().gains[method].gravity_feedforward == 0.0
