"""Physics tests of the serial 2R arm with gravity (docs/model.md#serial2r, ``ilcforce.plants.serial2r``).

What is checked, and against what:

* P1 and P2 (symmetric positive-definite inertia, skew-symmetric dD/dt - 2C) in joint and task space
  over a grid around the paper's task, for the nominal arm and the m2 x 1.4 arm.
* Kinematics: fk(ik(P)) = P in the working mode theta2 in (0, pi), J and dJ/dt against central
  finite differences, unreachable points raise.
* Gravity: G_q is the gradient of the potential energy V (an independent closed form) by finite
  differences, and the task-space G is J^-T G_q (eq. 4).
* Energy balance with gravity: along free motion T + V is conserved, and under a constant torque
  the change of T + V equals the work done, through RK4 whose fourth-order convergence is checked.
* An independent derivation: planar Newton-Euler (forces and moments on each link, no Lagrangian
  term used) against the plant's Lagrangian inverse dynamics, with gravity and a tip force.
* The compiled interface kernels against the public API; Serial2RParams validation.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ilcforce.plants import UnreachableError, make_plant, plant_class
from ilcforce.plants.serial2r import PARAM_NAMES, Serial2R, Serial2RParams

# The task region (docs/model.md#task: x in [0.05, 0.35] m, y in [0.400, 0.432] m), widened on every side.
GRID = [(float(x), float(y)) for x, y in itertools.product(np.linspace(0.03, 0.37, 5), np.linspace(0.33, 0.45, 4))]
GRID_IDS = [f"P=({x:.3f},{y:.3f})" for x, y in GRID]
RATES = [np.array(r) for r in ((1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, -1.0), (-0.7, 1.9))]
# Central differences with h = 1e-6 on O(1) functions of O(1) angles: truncation ~ h^2 / 6 ~ 2e-13,
# rounding ~ eps / h ~ 2e-10 relative; task-space matrices (built with J^-1, cond(J) up to ~10 on
# the grid) vary up to ~cond^2 faster, so 1e-7 keeps a margin of about 5 above the worst case.
H_FD = 1e-6
FD_RTOL = 1e-7
START = (0.35, 0.40)  # docs/model.md#task: the start pose of every iteration


def central_difference(f, x, direction, h=H_FD):
    x = np.asarray(x, float)
    d = np.asarray(direction, float)
    return (np.asarray(f(x + h * d)) - np.asarray(f(x - h * d))) / (2.0 * h)


@pytest.fixture(scope="module", params=[1.0, 1.4], ids=["nominal", "m2x1.4"])
def arm(request) -> Serial2R:
    return Serial2R(Serial2RParams().scaled("m2", request.param))


def test_registry_builds_the_arm():
    assert plant_class("serial2r") is Serial2R and isinstance(make_plant(Serial2RParams()), Serial2R)
    assert Serial2R.has_gravity


# --- 1. P1 and P2 ---------------------------------------------------------------------------------

@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_inertia_spd_and_skew(arm, point):
    theta = arm.inverse_kinematics(point)
    for name, m in (("Dq", arm.joint_inertia(theta)), ("D", arm.task_inertia(theta))):
        # the kernels store one off-diagonal entry: symmetric to rounding (1e-14 relative, ~50 ulp)
        np.testing.assert_allclose(m, m.T, rtol=0, atol=1e-14 * np.linalg.norm(m), err_msg=name)
        ev = np.linalg.eigvalsh(m)
        assert ev.min() > 1e-12 * ev.max(), f"{name} not positive definite at {point}: {ev}"
    for dtheta in RATES:
        for inertia, coriolis in ((arm.joint_inertia, arm.joint_coriolis), (arm.task_inertia, arm.task_coriolis)):
            d_dot = central_difference(inertia, theta, dtheta)
            skew = d_dot - 2.0 * coriolis(theta, dtheta)
            # dD/dt carries the FD error (FD_RTOL relative); C is exact to rounding
            scale = np.linalg.norm(d_dot) + 2.0 * np.linalg.norm(coriolis(theta, dtheta))
            np.testing.assert_allclose(skew + skew.T, 0.0, atol=FD_RTOL * scale,
                                       err_msg=f"Ddot - 2C not skew at {point}, dtheta={dtheta}")


# --- 2. kinematics --------------------------------------------------------------------------------

@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_kinematics_round_trip_and_derivatives(arm, point):
    theta = arm.inverse_kinematics(point)
    assert 0.0 < theta[1] < math.pi, "working mode theta2 in (0, pi)"
    # fk(ik(P)) = P: a few ulp of the 0.65 m reach (1e-15 m) through acos / atan2; 1e-13 m bar
    np.testing.assert_allclose(arm.forward_kinematics(theta), point, rtol=0, atol=1e-13)
    J = arm.jacobian(theta)
    J_fd = np.column_stack([central_difference(arm.forward_kinematics, theta, e) for e in np.eye(2)])
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=FD_RTOL * np.linalg.norm(J))
    for dtheta in RATES:
        dJ = arm.jacobian_derivative(theta, dtheta)
        dJ_fd = central_difference(arm.jacobian, theta, dtheta)
        np.testing.assert_allclose(dJ, dJ_fd, rtol=0, atol=FD_RTOL * (np.linalg.norm(J) * np.linalg.norm(dtheta)))


@pytest.mark.parametrize("point", [(0.7, 0.0), (0.0, 0.01), (0.0, 0.0)])
def test_unreachable_points_raise(point):
    with pytest.raises(UnreachableError):
        Serial2R().inverse_kinematics(point)


def test_poses_outside_working_mode_raise():
    arm = Serial2R()
    for theta in ((0.3, -0.5), (0.3, 0.0), (0.3, 3.5)):  # float pi is just inside (sin > 0)
        with pytest.raises(UnreachableError):
            arm.forward_kinematics(theta)
        assert arm.kernels().accel(arm.address, theta[0], theta[1], 0.0, 0.0)[0] == 0.0


# --- 3. gravity ------------------------------------------------------------------------------------

@pytest.mark.parametrize("point", GRID[::3])
def test_gravity_is_gradient_of_potential(arm, point):
    theta = arm.inverse_kinematics(point)
    G_fd = np.array([central_difference(lambda th: np.array(arm.potential_energy(th)), theta, e) for e in np.eye(2)])
    G = arm.gravity(theta)
    # V ~ 10 J: central-difference rounding eps V / h ~ 2e-9 N m, truncation h^2 V / 6 ~ 2e-12
    np.testing.assert_allclose(G, G_fd, rtol=0, atol=1e-7)
    J = arm.jacobian(theta)
    np.testing.assert_allclose(arm.task_gravity(theta), np.linalg.solve(J.T, G), rtol=1e-12,
                               atol=1e-12 * np.linalg.norm(G), err_msg="G = J^-T G_q (eq. 4)")


def test_gravity_switches_off_with_g_zero():
    arm = Serial2R(Serial2RParams(g=0.0))
    theta = arm.inverse_kinematics(START)
    assert np.array_equal(arm.gravity(theta), [0.0, 0.0])


# --- 4. energy balance with gravity -------------------------------------------------------------------

def rk4(arm, theta0, dtheta0, tau, step, n):
    def f(s):
        return np.concatenate([s[2:], arm.forward_dynamics(s[:2], s[2:], tau)])
    s = np.concatenate([theta0, dtheta0])
    out = [s]
    for _ in range(n):
        k1 = f(s)
        k2 = f(s + 0.5 * step * k1)
        k3 = f(s + 0.5 * step * k2)
        k4 = f(s + step * k3)
        s = s + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(s)
    return np.array(out)


def energy_error(arm, tau, step, duration=0.25):
    """(max |T + V - W - E(0)|, the energy exchanged max |V - V(0)| + max |W|) along RK4 from the
    start pose, W the work of a constant torque."""
    theta0 = arm.inverse_kinematics(START)
    tau = np.asarray(tau, float)
    states = rk4(arm, theta0, np.array([0.5, -0.8]), tau, step, round(duration / step))
    potential = np.array([arm.potential_energy(s[:2]) for s in states])
    work = np.array([tau @ (s[:2] - theta0) for s in states])
    energy = np.array([arm.kinetic_energy(s[:2], s[2:]) for s in states]) + potential - work
    exchanged = np.max(np.abs(potential - potential[0])) + np.max(np.abs(work))
    return float(np.max(np.abs(energy - energy[0]))), float(exchanged)


@pytest.mark.parametrize("tau", [(0.0, 0.0), (12.0, 3.0)], ids=["free", "constant-torque"])
def test_energy_balance_with_gravity(arm, tau):
    """d(T + V)/dt = tau . dtheta: T + V - tau . (theta - theta0) is conserved (the arm falls
    about 0.1 m under gravity in 0.25 s, so V changes by ~1 J; the error is RK4's alone)."""
    (coarse, _), (fine, exchanged) = energy_error(arm, tau, 2e-3), energy_error(arm, tau, 1e-3)
    # RK4's global error is O(h^4): halving h divides it by ~16 (11 allows for the asymptotic regime
    # not being reached exactly). A wrong G_q or V would leave an O(1) error that does not shrink
    # with h: relative to the energy exchanged, RK4 at h = 1 ms leaves ~1e-8; 1e-7 is the bar.
    assert coarse / fine > 11, f"energy error ratio {coarse / fine:.3g} (coarse {coarse:.3g}, fine {fine:.3g} J)"
    assert exchanged > 0.1, f"only {exchanged:.3g} J exchanged: the test would not see gravity"
    assert fine < 1e-7 * exchanged, f"energy error {fine:.3g} J of {exchanged:.3g} J exchanged"


# --- 5. Newton-Euler against the Lagrangian ---------------------------------------------------------

def newton_euler(pr: Serial2RParams, theta, dtheta, ddtheta, f_tip) -> np.ndarray:
    """Joint torques from forces and moments on each rigid link (planar, z moments).

    Link i has absolute angle phi_i, rate w_i, acceleration a_i; centre-of-mass acceleration
    a_c = a_joint + Lc (a_i e_perp - w_i^2 e). Link 2: F12 + m2 g + f_tip = m2 a_c2 and
    tau2 + (E - c2) x F12 + (P - c2) x f_tip = I2 a_2. Link 1: F01 - F12 + m1 g = m1 a_c1 and
    tau1 - tau2 + (0 - c1) x F01 - (E - c1) x F12 = I1 a_1.
    """
    def e(phi):
        return np.array([math.cos(phi), math.sin(phi)])

    def ep(phi):
        return np.array([-math.sin(phi), math.cos(phi)])

    def cross(a, b):
        return a[0] * b[1] - a[1] * b[0]

    phi1, phi2 = theta[0], theta[0] + theta[1]
    w1, w2 = dtheta[0], dtheta[0] + dtheta[1]
    a1, a2 = ddtheta[0], ddtheta[0] + ddtheta[1]
    gvec = np.array([0.0, -pr.g])
    E = pr.L1 * e(phi1)
    c1 = pr.Lc1 * e(phi1)
    c2 = E + pr.Lc2 * e(phi2)
    P = E + pr.L2 * e(phi2)
    acc_c1 = pr.Lc1 * (a1 * ep(phi1) - w1 * w1 * e(phi1))
    acc_E = pr.L1 * (a1 * ep(phi1) - w1 * w1 * e(phi1))
    acc_c2 = acc_E + pr.Lc2 * (a2 * ep(phi2) - w2 * w2 * e(phi2))
    F12 = pr.m2 * acc_c2 - pr.m2 * gvec - f_tip
    tau2 = pr.I2 * a2 - cross(E - c2, F12) - cross(P - c2, f_tip)
    F01 = pr.m1 * acc_c1 - pr.m1 * gvec + F12
    tau1 = pr.I1 * a1 + tau2 - cross(-c1, F01) + cross(E - c1, F12)
    return np.array([tau1, tau2])


STATES = [(p, np.array(d), np.array(a), np.array(f)) for p, d, a, f in (
    (START, (0.0, 0.0), (0.0, 0.0), (0.0, 0.0)),
    ((0.2, 0.41), (1.3, -0.7), (4.0, -9.0), (0.0, -20.0)),
    ((0.05, 0.432), (-2.0, 3.0), (-15.0, 6.0), (1.5, -31.9)),
    ((0.3, 0.35), (0.4, 0.9), (2.0, 2.0), (-3.0, 5.0)),
)]


@pytest.mark.parametrize("state", STATES, ids=[f"P={s[0]}" for s in STATES])
def test_inverse_dynamics_matches_newton_euler(arm, state):
    point, dtheta, ddtheta, f_tip = state
    theta = arm.inverse_kinematics(point)
    tau = arm.inverse_dynamics(theta, dtheta, ddtheta, f_tip)
    tau_ne = newton_euler(arm.params, theta, dtheta, ddtheta, f_tip)
    # both are exact closed forms in float64 over terms of ~30 N m: rounding ~1e-15 relative to
    # the largest term, so 1e-12 of the largest of |tau| and the gravity torque is the bar
    scale = max(np.linalg.norm(tau), np.linalg.norm(arm.gravity(theta)))
    np.testing.assert_allclose(tau, tau_ne, rtol=0, atol=1e-12 * scale)
    # forward dynamics inverts it (a 2x2 solve with cond(Dq) ~ 10: 1e-12 relative)
    ddtheta_back = arm.forward_dynamics(theta, dtheta, tau, f_tip)
    np.testing.assert_allclose(ddtheta_back, ddtheta, rtol=0, atol=1e-11 * max(1.0, np.linalg.norm(ddtheta)))


@pytest.mark.parametrize("point", GRID[::4])
def test_task_model_is_eq4_and_kernels_agree(arm, point):
    theta = arm.inverse_kinematics(point)
    dtheta = np.array([0.8, -1.1])
    J = arm.jacobian(theta)
    Ji = np.linalg.inv(J)
    Dq, Cq = arm.joint_inertia(theta), arm.joint_coriolis(theta, dtheta)
    dJ = arm.jacobian_derivative(theta, dtheta)
    D = Ji.T @ Dq @ Ji
    C = Ji.T @ (Cq - Dq @ Ji @ dJ) @ Ji
    np.testing.assert_allclose(arm.task_inertia(theta), D, rtol=0, atol=1e-12 * np.linalg.norm(D))
    np.testing.assert_allclose(arm.task_coriolis(theta, dtheta), C, rtol=0, atol=1e-12 * np.linalg.norm(C))
    out = arm.kernels().accel(arm.address, theta[0], theta[1], dtheta[0], dtheta[1])
    b = Cq @ dtheta + arm.gravity(theta)
    np.testing.assert_allclose(out[9:11], b, rtol=0, atol=1e-13 * np.linalg.norm(b))
    np.testing.assert_allclose([[out[11], out[12]], [out[12], out[13]]], np.linalg.inv(Dq), rtol=1e-12)
    np.testing.assert_allclose(out[7:9], dJ @ dtheta, rtol=0, atol=1e-14 * (1 + np.linalg.norm(dJ)))


# --- 6. parameters ----------------------------------------------------------------------------------

@pytest.mark.parametrize("name", PARAM_NAMES)
def test_params_rejected(name):
    for bad in (-1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match=f"plant.serial2r.{name}"):
            Serial2RParams(**{name: bad})
    if name != "g":
        with pytest.raises(ValueError, match=f"plant.serial2r.{name}"):
            Serial2RParams(**{name: 0.0})


def test_scaled_changes_one_parameter():
    base = Serial2RParams()
    heavy = base.scaled("m2", 1.4)
    assert [n for n in PARAM_NAMES if getattr(heavy, n) != getattr(base, n)] == ["m2"]
    assert heavy.m2 == pytest.approx(1.26)


def test_task_gravity_along_a_path_is_the_pointwise_g():
    arm = Serial2R()
    path = np.array([START, (0.2, 0.41), (0.05, 0.432)])
    along = arm.task_gravity_along(path)
    assert along.shape == (3, 2)
    for pos, g in zip(path, along):
        theta = arm.inverse_kinematics(pos)
        # J^-T G_q by numpy's solve against the kernel's adjugate form: cond(J) < 10, a few ulp
        np.testing.assert_allclose(g, np.linalg.solve(arm.jacobian(theta).T, arm.gravity(theta)), rtol=1e-13)
    # the weight of the arm (2.1 kg x 9.81 = 20.6 N) is carried mostly along y at the start pose
    assert 5.0 < along[0, 1] < 20.6
