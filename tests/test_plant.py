"""Physics tests of the five-bar plant (docs/model.md#fivebar, ``ilcforce.plants.fivebar``).

What is checked, and against what:

* Properties P1 and P2 (symmetric positive-definite inertia, skew-symmetric dD/dt - 2C) in joint space
  and task space over a grid of the task region, for the nominal plant and the m3 x 1.4 plant.
* Kinematics: fk(ik(P)) = P, loop closure, the elbows-out working mode, and every analytic
  derivative (J, R = dphi/dtheta, dJ/dt) against central finite differences.
* The model's statement (docs/model.md#fivebar) that cond(J) stays between about 1.4 and 1.7 along the paper's task.
* Free motion conserves kinetic energy, and with a constant torque the energy gained equals the work
  done, both through a fixed-step RK4 whose fourth-order convergence is itself checked.
* The fast model against a slow, independent reference (bottom of this file): the open-tree
  Lagrangian with explicit link centre-of-mass Jacobians, Christoffel symbols from complex-step
  derivatives, and the loop closure imposed by Lagrange multipliers, with no use of the plant's
  rho = dq'/dtheta projection.
* FiveBarParams validation and ``scaled``.

Every tolerance is written next to the quantity it bounds, with the error source that sets it.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from ilcforce.plants.fivebar import (
    PARAM_NAMES,
    FiveBar,
    FiveBarParams,
    UnreachableError,
    _accel_terms,
    _dynamics,
    _kinematics,
    _task_model,
)

EPS = np.finfo(float).eps  # 2.2e-16

# ---------------------------------------------------------------------------------------------
# Grids
# ---------------------------------------------------------------------------------------------

# The task region (docs/model.md#task): x_d spans [0.05, 0.35] m, y spans [0.400, 0.432] m; the grid
# is wider on every side so that the properties are checked around the task, not just on it.
GRID_X = np.linspace(0.03, 0.37, 6)  # m
GRID_Y = np.linspace(0.33, 0.45, 5)  # m
GRID = [(float(x), float(y)) for x, y in itertools.product(GRID_X, GRID_Y)]
GRID_IDS = [f"P=({x:.3f},{y:.3f})" for x, y in GRID]

# Joint-rate directions (rad/s): each actuator alone, both together (a translation of P), both
# opposed (the "squeeze" that drives the passive links fastest), and a generic one.
RATES = [np.array(r) for r in ((1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, -1.0), (-0.7, 1.9))]

# Central-difference step (rad, or s along a rate of O(1) rad/s). The error of a central difference
# of a function f of O(1)-radian angles is ~ h^2 |f'''| / 6 (truncation) + eps |f| / h (rounding):
# with h = 1e-6 that is ~ 2e-13 |f| + 2e-10 |f|, i.e. ~ 1e-10 relative to the function's scale.
# Near the edge of the grid (cond(J) up to ~7) the task-space matrices, built with J^-1, vary up
# to ~cond^2 ~ 50 times faster, so FD_RTOL = 1e-7 keeps a margin of about 20 on top of that.
H_FD = 1e-6
FD_RTOL = 1e-7


def central_difference(f, x, direction, h=H_FD):
    """(f(x + h d) - f(x - h d)) / (2 h): the directional derivative of f, error O(h^2)."""
    x = np.asarray(x, float)
    d = np.asarray(direction, float)
    return (np.asarray(f(x + h * d)) - np.asarray(f(x - h * d))) / (2.0 * h)


def fd_jacobian(f, x, h=H_FD):
    """Columns d f / d x_k by central differences, shape (len(f(x)), len(x))."""
    x = np.asarray(x, float)
    return np.column_stack([central_difference(f, x, np.eye(len(x))[k], h) for k in range(len(x))])


def wrap_angle(a):
    """a mapped to (-pi, pi]; used so finite differences of atan2 angles never see a 2 pi jump."""
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


@pytest.fixture(scope="module")
def plant() -> FiveBar:
    return FiveBar()


@pytest.fixture(scope="module")
def heavy_plant() -> FiveBar:
    """The true plant from iteration 10 on (docs/model.md#perturbation): m3 x 1.4, I3 unchanged."""
    return FiveBar(FiveBarParams().scaled("m3", 1.4))


# ---------------------------------------------------------------------------------------------
# 1. Properties P1 (SPD) and P2 (skew symmetry), joint space and task space
# ---------------------------------------------------------------------------------------------

# Symmetry: the kernels store a single off-diagonal entry, so D is symmetric to the last bit; 1e-14
# relative (~50 ulp) is the scale of rounding and catches any asymmetric assembly.
SYM_RTOL = 1e-14


def check_spd(name: str, matrix: np.ndarray, where: str) -> None:
    scale = np.linalg.norm(matrix)
    np.testing.assert_allclose(matrix, matrix.T, rtol=0, atol=SYM_RTOL * scale,
                               err_msg=f"{name} not symmetric at {where}")
    eigenvalues = np.linalg.eigvalsh(matrix)
    # Positive definiteness must hold well above rounding: eigenvalues below ~1e-12 of the largest
    # would be indistinguishable from a singular inertia, so that is the bar.
    assert eigenvalues.min() > 1e-12 * eigenvalues.max(), (
        f"{name} not positive definite at {where}: eigenvalues {eigenvalues}")


def check_skew(plant: FiveBar, theta: np.ndarray, dtheta: np.ndarray, where: str) -> None:
    """x^T (dD/dt - 2 C) x = 0 for all x, in joint space (Dq, Cq) and task space (D, C).

    dD/dt along the motion is dD/dtheta . dtheta, taken by a central difference along dtheta.
    """
    pairs = {
        "joint space (Dq, Cq)": (plant.joint_inertia, plant.joint_coriolis),
        "task space (D, C)": (plant.task_inertia, plant.task_coriolis),
    }
    rng = np.random.default_rng(1)
    probes = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), *rng.standard_normal((4, 2))]
    for space, (inertia, coriolis) in pairs.items():
        d_dot = central_difference(inertia, theta, dtheta)
        skew = d_dot - 2.0 * coriolis(theta, dtheta)
        # dD/dt carries the FD error (FD_RTOL relative to D's rate of change) and C is exact to
        # rounding, so x^T (Ddot - 2C) x is bounded by FD_RTOL ||Ddot|| ||x||^2.
        scale = np.linalg.norm(d_dot) + np.linalg.norm(2.0 * coriolis(theta, dtheta))
        for x in probes:
            value = float(x @ skew @ x)
            assert abs(value) <= FD_RTOL * scale * float(x @ x), (
                f"{space}: x^T (Ddot - 2C) x = {value:.3e} for x = {x} at {where}, "
                f"||Ddot|| = {np.linalg.norm(d_dot):.3e}")
        np.testing.assert_allclose(skew + skew.T, 0.0, atol=FD_RTOL * scale,
                                   err_msg=f"{space}: Ddot - 2C not skew-symmetric at {where}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_inertia_symmetric_positive_definite(plant, point):
    theta = plant.inverse_kinematics(point)
    check_spd("Dq", plant.joint_inertia(theta), f"P={point}")
    check_spd("D", plant.task_inertia(theta), f"P={point}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_ddot_minus_2c_skew_symmetric(plant, point):
    theta = plant.inverse_kinematics(point)
    for dtheta in RATES:
        check_skew(plant, theta, dtheta, f"P={point}, dtheta={dtheta}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_task_model_is_eq4_of_joint_model(plant, point):
    """D = J^-T Dq J^-1 and C = J^-T (Cq - Dq J^-1 dJ) J^-1 (eq. 4), recomputed with numpy solves.

    Only rounding separates the two, amplified by cond(J)^2 (< 50 on the grid): rtol 1e-12.
    """
    theta = plant.inverse_kinematics(point)
    J = plant.jacobian(theta)
    Jinv = np.linalg.inv(J)
    Dq = plant.joint_inertia(theta)
    D = Jinv.T @ Dq @ Jinv
    np.testing.assert_allclose(plant.task_inertia(theta), D, rtol=1e-12, atol=1e-12 * np.linalg.norm(D),
                               err_msg=f"D != J^-T Dq J^-1 at P={point}")
    for dtheta in RATES:
        Cq = plant.joint_coriolis(theta, dtheta)
        dJ = plant.jacobian_derivative(theta, dtheta)
        C = Jinv.T @ (Cq - Dq @ Jinv @ dJ) @ Jinv
        np.testing.assert_allclose(plant.task_coriolis(theta, dtheta), C, rtol=0,
                                   atol=1e-12 * (np.linalg.norm(C) + np.linalg.norm(D)),
                                   err_msg=f"C != eq. 4 at P={point}, dtheta={dtheta}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_compiled_kernels_agree_with_public_api(plant, point):
    """The simulator calls the kernels directly; their packed outputs must mean what the docs say.

    Same arithmetic on both sides up to a 2x2 inverse and products: rtol 1e-13 (rounding).
    """
    p = plant.packed
    theta = plant.inverse_kinematics(point)
    for dtheta in RATES:
        args = (p, theta[0], theta[1], dtheta[0], dtheta[1])
        J = plant.jacobian(theta)
        dJ = plant.jacobian_derivative(theta, dtheta)
        Dq = plant.joint_inertia(theta)
        Cq = plant.joint_coriolis(theta, dtheta)
        acc = _accel_terms(*args)
        task = _task_model(*args)
        assert acc[0] and task[0], f"kernel reports an unreachable pose at P={point}"
        where = f"P={point}, dtheta={dtheta}"
        np.testing.assert_allclose(acc[1:3], point, rtol=0, atol=1e-12, err_msg=f"_accel_terms P at {where}")
        np.testing.assert_allclose(np.array(acc[3:7]).reshape(2, 2), J, rtol=1e-13, err_msg=f"J at {where}")
        np.testing.assert_allclose(acc[7:9], dJ @ dtheta, rtol=1e-13, atol=1e-15, err_msg=f"dJ dtheta at {where}")
        np.testing.assert_allclose(acc[9:11], Cq @ dtheta, rtol=1e-13, atol=1e-15, err_msg=f"Cq dtheta at {where}")
        Mi = np.array([[acc[11], acc[12]], [acc[12], acc[13]]])
        np.testing.assert_allclose(Mi @ Dq, np.eye(2), rtol=0, atol=1e-12, err_msg=f"Dq^-1 at {where}")
        np.testing.assert_allclose(task[3:5], J @ dtheta, rtol=1e-13, atol=1e-15, err_msg=f"Pdot at {where}")


def test_kernels_flag_poses_outside_working_mode(plant):
    """theta = (pi, 0): |E1 E2| = L1 + L2 + L5 > L3 + L4, the loop cannot close."""
    out = _kinematics(plant.packed, math.pi, 0.0)
    assert not out[0] and all(math.isnan(v) for v in out[1:]), f"_kinematics returned {out}"
    assert not _dynamics(plant.packed, math.pi, 0.0, 1.0, 1.0)[0]
    with pytest.raises(UnreachableError, match=r"outside the elbows-out working mode"):
        plant.forward_kinematics((math.pi, 0.0))
    with pytest.raises(UnreachableError):
        plant.forward_dynamics((math.pi, 0.0), (0.0, 0.0), (0.0, 0.0))


# ---------------------------------------------------------------------------------------------
# 2. Kinematics: round trip, unreachable points, loop closure, working mode
# ---------------------------------------------------------------------------------------------

# Positions: ik and fk each take a few trig calls and square roots of O(0.3 m) quantities, each
# correct to ~1 ulp (~5e-17 m), amplified by cond(J) < 7; 1e-12 m is ~1e3 times that.
POS_ATOL = 1e-12  # m


def cross2(a, b) -> float:
    return float(a[0] * b[1] - a[1] * b[0])


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_forward_inverse_kinematics_round_trip(plant, point):
    theta = plant.inverse_kinematics(point)
    np.testing.assert_allclose(plant.forward_kinematics(theta), point, rtol=0, atol=POS_ATOL,
                               err_msg=f"fk(ik(P)) != P, theta = {theta}")


# beyond the outer reach (L1 + L3 = 0.58 m from B1), and inside the inner hole (|L3 - L1| = 0.025 m)
@pytest.mark.parametrize("point", [(1.0, 1.0), (-0.6, 0.1), (0.15, 0.9), (0.005, 0.01)])
def test_inverse_kinematics_unreachable_point_raises(plant, point):
    x, y = point
    with pytest.raises(UnreachableError, match=rf"\({x:.6g}, {y:.6g}\)") as info:
        plant.inverse_kinematics(point)
    assert isinstance(info.value, ValueError)


def test_inverse_kinematics_never_returns_another_pose(plant):
    """Over the whole plane around the robot, ik either raises UnreachableError or returns angles
    whose forward kinematics is P again. 1e-9 m: the round trip is exact to ~1e-14 m on this grid
    (measured 4.5e-15 m), and rounding grows only near singular edges, as eps / sqrt(1 - c^2) with c
    the acos argument; 1e-9 m leaves room for that while a wrong pose misses by centimetres.

    A point P reached only in the lower assembly (P right of E1 -> E2) with elbows out has valid
    elbows-out angles from the ik formulas of docs/model.md#fivebar, but fk of those angles is the *upper*
    intersection, a different point: ik must then raise, not return them.
    """
    xs = np.linspace(-0.6, 0.9, 61)  # m, 2.5 cm spacing
    ys = np.linspace(-0.6, 0.6, 48)  # m, even count: never exactly on the base line (see next test)
    wrong = []
    for x, y in itertools.product(xs, ys):
        try:
            theta = plant.inverse_kinematics((x, y))
        except UnreachableError:
            continue
        miss = float(np.linalg.norm(plant.forward_kinematics(theta) - (x, y)))
        if miss > 1e-9:
            wrong.append(f"P=({x:.4f}, {y:.4f}) -> theta={np.round(theta, 6)} -> fk={np.round(plant.forward_kinematics(theta), 6)}")
    assert not wrong, f"ik returned angles of another pose at {len(wrong)} points, e.g. {wrong[:3]}"


@pytest.mark.parametrize("point", [(0.0, 0.0), (0.3048, 0.0)], ids=["at B1", "at B2"])
def test_inverse_kinematics_at_base_joint_raises_unreachable(plant, point):
    """r1 = 0 (or r2 = 0): the ik formula divides by it; the point is unreachable (|L3 - L1| > 0)."""
    with pytest.raises(UnreachableError):
        plant.inverse_kinematics(point)


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_loop_closure_and_elbows_out(plant, point):
    pr = plant.params
    theta = plant.inverse_kinematics(point)
    phi3, phi4 = plant.passive_angles(theta)
    P = np.asarray(point)
    B1, B2 = np.zeros(2), np.array([pr.L5, 0.0])
    E1 = pr.L1 * np.array([math.cos(theta[0]), math.sin(theta[0])])
    E2 = B2 + pr.L2 * np.array([math.cos(theta[1]), math.sin(theta[1])])
    u3 = np.array([math.cos(phi3), math.sin(phi3)])
    u4 = np.array([math.cos(phi4), math.sin(phi4)])
    np.testing.assert_allclose(E1 + pr.L3 * u3, P, rtol=0, atol=POS_ATOL, err_msg="E1 + L3 u3 != P")
    np.testing.assert_allclose(E2 + pr.L4 * u4, P, rtol=0, atol=POS_ATOL, err_msg="E2 + L4 u4 != P")
    np.testing.assert_allclose([np.linalg.norm(P - E1), np.linalg.norm(P - E2)], [pr.L3, pr.L4],
                               rtol=0, atol=POS_ATOL, err_msg="distal link lengths not preserved")
    # elbows out (docs/model.md#fivebar); on the grid these cross products are > 1e-3 m^2, far from 0
    assert cross2(P - B1, E1 - B1) > 0, f"E1 not left of P - B1 at P={point}"
    assert cross2(P - B2, E2 - B2) < 0, f"E2 not right of P - B2 at P={point}"
    # forward kinematics takes the intersection to the left of E1 -> E2 (upper assembly)
    assert cross2(E2 - E1, P - E1) > 0, f"P not left of E1 -> E2 at P={point}"


# ---------------------------------------------------------------------------------------------
# 3. Analytic derivatives against finite differences
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_jacobian_matches_finite_differences(plant, point):
    theta = plant.inverse_kinematics(point)
    J = plant.jacobian(theta)
    J_fd = fd_jacobian(plant.forward_kinematics, theta)
    np.testing.assert_allclose(J, J_fd, rtol=0, atol=FD_RTOL * np.linalg.norm(J),
                               err_msg=f"J != d fk / d theta at P={point}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_passive_jacobian_matches_finite_differences(plant, point):
    theta = plant.inverse_kinematics(point)
    R = plant.passive_jacobian(theta)

    def phi_relative(th):  # angles relative to the centre, so the difference never wraps
        return wrap_angle(plant.passive_angles(th) - plant.passive_angles(theta))

    R_fd = fd_jacobian(phi_relative, theta)
    np.testing.assert_allclose(R, R_fd, rtol=0, atol=FD_RTOL * np.linalg.norm(R),
                               err_msg=f"R != d phi / d theta at P={point}")


@pytest.mark.parametrize("point", GRID, ids=GRID_IDS)
def test_jacobian_derivative_matches_finite_differences(plant, point):
    theta = plant.inverse_kinematics(point)
    for dtheta in RATES:
        dJ = plant.jacobian_derivative(theta, dtheta)
        dJ_fd = central_difference(plant.jacobian, theta, dtheta)
        # J's own scale times |dtheta| bounds the FD rounding term, so include it in the scale
        scale = np.linalg.norm(dJ) + np.linalg.norm(plant.jacobian(theta)) * np.linalg.norm(dtheta)
        np.testing.assert_allclose(dJ, dJ_fd, rtol=0, atol=FD_RTOL * scale,
                                   err_msg=f"dJ/dt != d J / d theta . dtheta at P={point}, dtheta={dtheta}")


# ---------------------------------------------------------------------------------------------
# 4. The model's conditioning along the paper's task
# ---------------------------------------------------------------------------------------------


def test_jacobian_condition_along_paper_task(plant):
    """docs/model.md#fivebar: along the task cond(J) stays between about 1.4 and 1.7 (measured: 1.37 to 1.73).

    x_d(t) = 0.15 cos(pi t / 2) + 0.2 m; y(t) = y_e + F_yd(t) / K_e goes from 0.400 to 0.432 m.
    The band 1.3..1.8 is the design's "about", not a numerical tolerance.
    """
    t = np.linspace(0.0, 2.0, 50)
    x = 0.15 * np.cos(np.pi * t / 2.0) + 0.2
    y = 0.4 + (5.0 * np.sin(np.pi * t) + 5.0 * (np.exp(t) - 1.0)) / 1000.0
    assert abs(y[0] - 0.400) < 1e-12 and abs(y[-1] - 0.432) < 1e-3
    cond = np.array([np.linalg.cond(plant.jacobian(plant.inverse_kinematics((a, b)))) for a, b in zip(x, y)])
    bad = np.flatnonzero((cond <= 1.3) | (cond >= 1.8))
    assert bad.size == 0, f"cond(J) outside (1.3, 1.8) at t = {t[bad]}: {cond[bad]}"


# ---------------------------------------------------------------------------------------------
# 5. Energy: free motion conserves it; a constant torque adds exactly its work
# ---------------------------------------------------------------------------------------------

DURATION = 0.2  # s
START = (0.2, 0.4)  # m, in the middle of the task


def rk4(plant: FiveBar, theta0, dtheta0, tau, step: float, n_steps: int) -> np.ndarray:
    """Classical fixed-step RK4 on (theta, dtheta); returns the states, shape (n_steps + 1, 4)."""

    def rhs(state):
        return np.concatenate([state[2:], plant.forward_dynamics(state[:2], state[2:], tau)])

    state = np.concatenate([theta0, dtheta0]).astype(float)
    states = [state]
    for _ in range(n_steps):
        k1 = rhs(state)
        k2 = rhs(state + 0.5 * step * k1)
        k3 = rhs(state + 0.5 * step * k2)
        k4 = rhs(state + step * k3)
        state = state + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        states.append(state)
    return np.array(states)


def energy_drift(plant: FiveBar, dtheta0, step: float) -> float:
    theta0 = plant.inverse_kinematics(START)
    states = rk4(plant, theta0, np.asarray(dtheta0, float), np.zeros(2), step, round(DURATION / step))
    energy = np.array([plant.kinetic_energy(s[:2], s[2:]) for s in states])
    return float(np.max(np.abs(energy - energy[0])) / energy[0])


@pytest.mark.parametrize("dtheta0", [(1.0, -1.0), (1.0, 0.0), (-0.5, 1.2)], ids=str)
def test_free_motion_conserves_kinetic_energy(plant, dtheta0):
    """tau = 0, no wall, no gravity (horizontal plane): T = dtheta^T Dq dtheta / 2 is constant.

    The only error is RK4's, O(step^4). Two checks pin it down:
    * at step = 1 ms the relative drift is < 1e-8 (measured 1.5e-9 for the fastest, squeezing
      motion (1, -1), whose passive links turn at several rad/s; (rate x step)^4 ~ 1e-12 per step);
    * halving a coarse step (10 ms -> 5 ms) divides the drift by ~2^4 = 16 (we accept 10..24). A
      model error (e.g. a Coriolis term inconsistent with Dq) would give a drift that does not
      shrink with the step, so this separates the integrator from the model.
    """
    fine = energy_drift(plant, dtheta0, 1e-3)
    assert fine < 1e-8, f"relative kinetic energy drift {fine:.3e} over {DURATION} s at 1 ms"
    coarse, half = energy_drift(plant, dtheta0, 1e-2), energy_drift(plant, dtheta0, 5e-3)
    if coarse > 1e-11:  # above rounding, so the ratio is meaningful
        ratio = coarse / half
        assert 10.0 < ratio < 24.0, (
            f"energy drift not O(step^4): {coarse:.3e} at 10 ms, {half:.3e} at 5 ms, ratio {ratio:.2f}")


def test_constant_torque_power_balance(plant):
    """E(T) - E(0) = int_0^T tau . dtheta dt for a constant tau (no other generalised force).

    Integrated by RK4 at 0.2 ms (1000 steps), the work by the trapezoid rule on the same grid.
    Error budget relative to the energy gained (~2e-2 J):
    * trapezoid: + (h^2 / 12) [g'(T) - g'(0)] (Euler-Maclaurin) with g = tau . dtheta and
      g' = tau . ddtheta, ~1e-8 relative here. It is computed below; the remainder after correcting
      by it is O(h^4), ~1e-14 relative;
    * RK4: O(h^4); the free-motion test measures 1.5e-9 relative over 0.2 s at 1 ms for a faster
      motion, so (0.2)^4 x that ~ 2e-12 at 0.2 ms.
    So the raw trapezoid must agree within 2x its Euler-Maclaurin estimate plus 1e-10 relative, and
    the corrected one (and the exact tau . (theta(T) - theta(0))) within 1e-10 relative.
    """
    step, n_steps = 2e-4, 1000
    tau = np.array([0.05, -0.03])  # N m, a few times Dq * 1 rad/s^2
    theta0 = plant.inverse_kinematics(START)
    dtheta0 = np.array([1.0, 0.5])
    states = rk4(plant, theta0, dtheta0, tau, step, n_steps)
    energy = np.array([plant.kinetic_energy(s[:2], s[2:]) for s in states])
    gained = energy[-1] - energy[0]
    power = states[:, 2:] @ tau
    work = float(np.sum(0.5 * (power[1:] + power[:-1])) * step)
    d_power = [tau @ plant.forward_dynamics(s[:2], s[2:], tau) for s in (states[0], states[-1])]
    trapezoid_error = (step**2 / 12.0) * (d_power[1] - d_power[0])  # work_trapz - work_exact
    assert abs(gained) > 1e-3, f"test is vacuous: energy gained {gained:.3e} J"
    assert abs(work - gained) <= 2.0 * abs(trapezoid_error) + 1e-10 * abs(gained), (
        f"power balance: E(T) - E(0) = {gained:.12e} J, trapezoid work {work:.12e} J, "
        f"expected trapezoid error {trapezoid_error:.3e} J")
    np.testing.assert_allclose(work - trapezoid_error, gained, rtol=1e-10,
                               err_msg="power balance with the Euler-Maclaurin-corrected trapezoid")
    exact_work = float(tau @ (states[-1, :2] - states[0, :2]))  # tau constant: int tau.dtheta = tau.dtheta_total
    np.testing.assert_allclose(exact_work, gained, rtol=1e-10, err_msg="E(T) - E(0) != tau . (theta(T) - theta(0))")


# ---------------------------------------------------------------------------------------------
# 6. The fast model against a slow, independent reference (open tree + Lagrange multipliers)
# ---------------------------------------------------------------------------------------------
#
# Generalised coordinates of the open tree: q' = (theta1, theta2, phi3, phi4), all absolute angles.
# Link i's centre of mass c_i(q') and angular velocity w_i = Jw_i q'dot:
#   c1 = Lc1 e(theta1)                      Jw1 = (1, 0, 0, 0)
#   c2 = B2 + Lc2 e(theta2)                 Jw2 = (0, 1, 0, 0)
#   c3 = L1 e(theta1) + Lc3 e(phi3)         Jw3 = (0, 0, 1, 0)
#   c4 = B2 + L2 e(theta2) + Lc4 e(phi4)    Jw4 = (0, 0, 0, 1)
# with e(a) = (cos a, sin a) and e_perp(a) = de/da = (-sin a, cos a); Jc_i = d c_i / d q' is written
# out by hand. M(q') = sum_i m_i Jc_i^T Jc_i + I_i Jw_i^T Jw_i.
# Coriolis/centrifugal vector c_i = Gamma_ijk q'dot_j q'dot_k with the Christoffel symbols
# Gamma_ijk = (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) / 2; dM/dq by COMPLEX-STEP differentiation of M
# (M is built with numpy complex arithmetic, step 1e-30: no subtraction, so the derivative is exact
# to machine precision).
# Loop closure Phi(q') = E1 + L3 e(phi3) - E2 - L4 e(phi4) = 0, A = dPhi/dq' written analytically
# and checked against a complex step of Phi; the constraint acceleration term Adot q'dot is a
# complex step of A(q') q'dot along q'dot, checked against its closed form.
# Equations of motion: M q'ddot + c = B tau + A^T lambda + Jp^T f, B = [I; 0], Jp = dP/dq', f the
# external force on the end-effector.

COMPLEX_STEP = 1e-30


def _e(a):
    return np.array([np.cos(a), np.sin(a)])


def _e_perp(a):
    return np.array([-np.sin(a), np.cos(a)])


def ref_inertia(pr: FiveBarParams, q) -> np.ndarray:
    """Open-tree inertia M(q'), shape (4, 4); q' may be complex (for the complex step)."""
    th1, th2, ph3, ph4 = q
    z = np.zeros(2, dtype=np.result_type(np.asarray(q).dtype, float))
    Jc = [
        np.column_stack([pr.Lc1 * _e_perp(th1), z, z, z]),
        np.column_stack([z, pr.Lc2 * _e_perp(th2), z, z]),
        np.column_stack([pr.L1 * _e_perp(th1), z, pr.Lc3 * _e_perp(ph3), z]),
        np.column_stack([z, pr.L2 * _e_perp(th2), z, pr.Lc4 * _e_perp(ph4)]),
    ]
    Jw = np.eye(4)
    masses = (pr.m1, pr.m2, pr.m3, pr.m4)
    inertias = (pr.I1, pr.I2, pr.I3, pr.I4)
    # plain transposes (no conjugation), so the complex step stays analytic
    return sum(m * Jci.T @ Jci + inertia * np.outer(Jw[i], Jw[i])
               for i, (m, inertia, Jci) in enumerate(zip(masses, inertias, Jc)))


def ref_inertia_derivative(pr: FiveBarParams, q) -> np.ndarray:
    """dM/dq', shape (4, 4, 4) indexed [k, i, j] = dM_ij / dq_k, by complex step."""
    q = np.asarray(q, float)
    return np.array([np.imag(ref_inertia(pr, q + 1j * COMPLEX_STEP * np.eye(4)[k])) / COMPLEX_STEP
                     for k in range(4)])


def ref_coriolis_vector(pr: FiveBarParams, q, qd) -> np.ndarray:
    """c(q', q'dot) = Gamma_ijk q'dot_j q'dot_k, shape (4,)."""
    dM = ref_inertia_derivative(pr, q)  # [k, i, j]
    gamma = 0.5 * (np.einsum("kij->ijk", dM) + np.einsum("jik->ijk", dM) - np.einsum("ijk->ijk", dM))
    return np.einsum("ijk,j,k->i", gamma, qd, qd)


def ref_constraint(pr: FiveBarParams, q) -> np.ndarray:
    th1, th2, ph3, ph4 = q
    B2 = np.array([pr.L5, 0.0])
    return pr.L1 * _e(th1) + pr.L3 * _e(ph3) - B2 - pr.L2 * _e(th2) - pr.L4 * _e(ph4)


def ref_constraint_jacobian(pr: FiveBarParams, q) -> np.ndarray:
    """A = dPhi/dq', shape (2, 4), analytic."""
    th1, th2, ph3, ph4 = q
    return np.column_stack([pr.L1 * _e_perp(th1), -pr.L2 * _e_perp(th2),
                            pr.L3 * _e_perp(ph3), -pr.L4 * _e_perp(ph4)])


def ref_constraint_bias(pr: FiveBarParams, q, qd) -> np.ndarray:
    """Adot q'dot = d/ds [A(q' + s q'dot) q'dot] at s = 0, by complex step, shape (2,)."""
    q, qd = np.asarray(q, float), np.asarray(qd, float)
    return np.imag(ref_constraint_jacobian(pr, q + 1j * COMPLEX_STEP * qd) @ qd) / COMPLEX_STEP


def ref_end_effector_jacobian(pr: FiveBarParams, q) -> np.ndarray:
    """Jp = dP/dq' with P = E1 + L3 e(phi3), shape (2, 4)."""
    th1, _th2, ph3, _ph4 = q
    z = np.zeros(2)
    return np.column_stack([pr.L1 * _e_perp(th1), z, pr.L3 * _e_perp(ph3), z])


ACTUATION = np.vstack([np.eye(2), np.zeros((2, 2))])  # B: tau enters the theta rows only


def ref_state(plant: FiveBar, theta, dtheta, ddtheta=None):
    """Open-tree q', q'dot (and q'ddot) consistent with the loop closure.

    phi from plant.passive_angles (its loop closure is checked here to 1e-12 m); the passive rates
    and accelerations from A q'dot = 0 and A q'ddot = -Adot q'dot, never from plant's R.
    """
    pr = plant.params
    theta, dtheta = np.asarray(theta, float), np.asarray(dtheta, float)
    q = np.concatenate([theta, plant.passive_angles(theta)])
    closure = ref_constraint(pr, q)
    assert np.linalg.norm(closure) < 1e-12, f"passive angles do not close the loop: Phi = {closure}"
    A = ref_constraint_jacobian(pr, q)
    qd = np.concatenate([dtheta, np.linalg.solve(A[:, 2:], -A[:, :2] @ dtheta)])
    if ddtheta is None:
        return q, qd
    ddtheta = np.asarray(ddtheta, float)
    rhs = -A[:, :2] @ ddtheta - ref_constraint_bias(pr, q, qd)
    qdd = np.concatenate([ddtheta, np.linalg.solve(A[:, 2:], rhs)])
    return q, qd, qdd


def ref_inverse_dynamics(plant: FiveBar, theta, dtheta, ddtheta, force=(0.0, 0.0)) -> np.ndarray:
    """tau from [B A^T] [tau; lambda] = M q'ddot + c - Jp^T f."""
    pr = plant.params
    q, qd, qdd = ref_state(plant, theta, dtheta, ddtheta)
    rhs = ref_inertia(pr, q) @ qdd + ref_coriolis_vector(pr, q, qd) - ref_end_effector_jacobian(pr, q).T @ force
    system = np.hstack([ACTUATION, ref_constraint_jacobian(pr, q).T])
    return np.linalg.solve(system, rhs)[:2]


def ref_forward_dynamics(plant: FiveBar, theta, dtheta, tau, force=(0.0, 0.0)) -> np.ndarray:
    """ddtheta from the index-1 DAE [[M, -A^T], [A, 0]] [q'ddot; lambda] = [B tau + Jp^T f - c; -Adot q'dot]."""
    pr = plant.params
    q, qd = ref_state(plant, theta, dtheta)
    A = ref_constraint_jacobian(pr, q)
    kkt = np.block([[ref_inertia(pr, q), -A.T], [A, np.zeros((2, 2))]])
    rhs = np.concatenate([
        ACTUATION @ np.asarray(tau, float) + ref_end_effector_jacobian(pr, q).T @ np.asarray(force, float)
        - ref_coriolis_vector(pr, q, qd),
        -ref_constraint_bias(pr, q, qd),
    ])
    return np.linalg.solve(kkt, rhs)[:2]


def random_states(n: int, seed: int = 20240601):
    """n states in the task region: P uniform in the grid box, rates and accelerations N(0, 1)."""
    rng = np.random.default_rng(seed)
    return [(rng.uniform([GRID_X[0], GRID_Y[0]], [GRID_X[-1], GRID_Y[-1]]),
             rng.standard_normal(2), rng.standard_normal(2), 5.0 * rng.standard_normal(2))
            for _ in range(n)]


STATES = random_states(10)
STATE_IDS = [f"state{k}" for k in range(len(STATES))]

# The reference and the plant share no intermediate: both are exact formulas evaluated in float64
# (complex-step derivatives are exact to rounding), then a 2x2 or 4x4 solve whose condition number
# is < 1e2 in the task region. Rounding therefore leaves ~1e-14 relative; 1e-10 is the brief's
# "agreement to ~1e-10", keeping four orders of margin while any modelling error (a wrong term is
# O(1) relative) is caught.
REF_RTOL = 1e-10


def test_reference_model_self_consistency(plant):
    """Guard the reference itself: its analytic A against a complex step of Phi, its complex-step
    Adot q'dot against the closed form -sum_k (+-) L_k e(q_k) q'dot_k^2, and its Christoffel vector
    against Lagrange's c = Mdot q'dot - d/dq' (q'dot^T M q'dot) / 2 (all complex step: 1e-13)."""
    pr = plant.params
    for point, dtheta, _ddtheta, _force in STATES[:3]:
        q, qd = ref_state(plant, plant.inverse_kinematics(point), dtheta)
        A_cs = np.column_stack([np.imag(ref_constraint(pr, q + 1j * COMPLEX_STEP * np.eye(4)[k])) / COMPLEX_STEP
                                for k in range(4)])
        np.testing.assert_allclose(ref_constraint_jacobian(pr, q), A_cs, rtol=1e-13, atol=1e-15,
                                   err_msg="reference A != dPhi/dq'")
        signs_lengths = ((1, pr.L1), (-1, pr.L2), (1, pr.L3), (-1, pr.L4))
        closed_form = -sum(s * L * _e(q[k]) * qd[k] ** 2 for k, (s, L) in enumerate(signs_lengths))
        np.testing.assert_allclose(ref_constraint_bias(pr, q, qd), closed_form, rtol=1e-13, atol=1e-15,
                                   err_msg="reference Adot q'dot")
        dM = ref_inertia_derivative(pr, q)
        lagrange = np.einsum("k,kij,j->i", qd, dM, qd) - 0.5 * np.einsum("j,ijk,k->i", qd, dM, qd)
        np.testing.assert_allclose(ref_coriolis_vector(pr, q, qd), lagrange, rtol=1e-13, atol=1e-15,
                                   err_msg="reference Christoffel vector")


@pytest.mark.parametrize("state", STATES, ids=STATE_IDS)
def test_inverse_dynamics_matches_lagrange_multiplier_reference(plant, state):
    point, dtheta, ddtheta, _force = state
    theta = plant.inverse_kinematics(point)
    tau = plant.inverse_dynamics(theta, dtheta, ddtheta)
    tau_ref = ref_inverse_dynamics(plant, theta, dtheta, ddtheta)
    np.testing.assert_allclose(tau, tau_ref, rtol=REF_RTOL, atol=REF_RTOL * np.linalg.norm(tau_ref),
                               err_msg=f"inverse dynamics at P={point}, dtheta={dtheta}, ddtheta={ddtheta}")


@pytest.mark.parametrize("state", STATES, ids=STATE_IDS)
def test_inverse_dynamics_with_end_effector_force(plant, state):
    """f (force on the robot) enters as -J^T f in tau; the reference adds Jp^T f on the open tree."""
    point, dtheta, ddtheta, force = state
    theta = plant.inverse_kinematics(point)
    tau = plant.inverse_dynamics(theta, dtheta, ddtheta, force)
    tau_ref = ref_inverse_dynamics(plant, theta, dtheta, ddtheta, force)
    np.testing.assert_allclose(tau, tau_ref, rtol=REF_RTOL, atol=REF_RTOL * np.linalg.norm(tau_ref),
                               err_msg=f"inverse dynamics with f={force} at P={point}")
    free = plant.inverse_dynamics(theta, dtheta, ddtheta)
    np.testing.assert_allclose(free - tau, plant.jacobian(theta).T @ force, rtol=1e-12,
                               atol=1e-14 * np.linalg.norm(force),
                               err_msg="inverse_dynamics(f) != inverse_dynamics(0) - J^T f")


@pytest.mark.parametrize("state", STATES, ids=STATE_IDS)
def test_forward_dynamics_matches_reference_and_round_trips(plant, state):
    point, dtheta, ddtheta, force = state
    theta = plant.inverse_kinematics(point)
    for f in (np.zeros(2), force):
        tau = plant.inverse_dynamics(theta, dtheta, ddtheta, f)
        # round trip: Dq^-1 (Dq a + b - b) = a up to cond(Dq) (< 1e2) times rounding
        np.testing.assert_allclose(plant.forward_dynamics(theta, dtheta, tau, f), ddtheta, rtol=1e-11,
                                   atol=1e-11 * np.linalg.norm(ddtheta),
                                   err_msg=f"forward(inverse(ddtheta)) != ddtheta at P={point}, f={f}")
        np.testing.assert_allclose(plant.forward_dynamics(theta, dtheta, tau, f),
                                   ref_forward_dynamics(plant, theta, dtheta, tau, f), rtol=REF_RTOL,
                                   atol=REF_RTOL * np.linalg.norm(ddtheta),
                                   err_msg=f"forward dynamics vs the DAE reference at P={point}, f={f}")


@pytest.mark.parametrize("state", STATES, ids=STATE_IDS)
def test_kinetic_energy_matches_open_tree(plant, state):
    """dtheta^T Dq dtheta / 2 = q'dot^T M q'dot / 2 with q'dot from the constraint (rounding: 1e-12)."""
    point, dtheta, _ddtheta, _force = state
    theta = plant.inverse_kinematics(point)
    q, qd = ref_state(plant, theta, dtheta)
    np.testing.assert_allclose(plant.kinetic_energy(theta, dtheta), 0.5 * qd @ ref_inertia(plant.params, q) @ qd,
                               rtol=1e-12, err_msg=f"kinetic energy at P={point}, dtheta={dtheta}")


@pytest.mark.parametrize("state", STATES[:4], ids=STATE_IDS[:4])
def test_heavy_plant_matches_reference(heavy_plant, state):
    """The m3 x 1.4 plant goes through the same kernels with another packed vector: check it too."""
    point, dtheta, ddtheta, force = state
    theta = heavy_plant.inverse_kinematics(point)
    tau_ref = ref_inverse_dynamics(heavy_plant, theta, dtheta, ddtheta, force)
    np.testing.assert_allclose(heavy_plant.inverse_dynamics(theta, dtheta, ddtheta, force), tau_ref,
                               rtol=REF_RTOL, atol=REF_RTOL * np.linalg.norm(tau_ref),
                               err_msg=f"m3 x 1.4 plant inverse dynamics at P={point}")


# ---------------------------------------------------------------------------------------------
# 7. FiveBarParams
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [-0.1, 0.0, math.nan, math.inf, -math.inf], ids=str)
@pytest.mark.parametrize("name", PARAM_NAMES)
def test_params_reject_non_positive_or_non_finite(name, bad):
    with pytest.raises(ValueError, match=rf"\b{name}\b"):
        FiveBarParams(**{name: bad})


def test_params_reject_non_numbers():
    with pytest.raises(ValueError, match=r"\bL3\b"):
        FiveBarParams(L3="0.3")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"\bm1\b"):
        FiveBarParams(m1=True)


def test_params_defaults_are_table_1():
    pr = FiveBarParams()
    assert (pr.L1, pr.L2, pr.L3, pr.L4, pr.L5) == (0.2794, 0.2794, 0.3048, 0.3048, 0.3048)
    assert (pr.Lc1, pr.Lc2, pr.Lc3, pr.Lc4) == (0.1466, 0.1410, 0.1581, 0.1467)
    assert (pr.m1, pr.m2, pr.m3, pr.m4) == (0.2451, 0.2352, 0.2611, 0.2611)
    assert (pr.I1, pr.I2, pr.I3, pr.I4) == (2.779e-3, 2.607e-3, 3.476e-3, 3.476e-3)
    np.testing.assert_array_equal(pr.as_array(), [getattr(pr, n) for n in PARAM_NAMES],
                                  err_msg="as_array order != PARAM_NAMES")


def test_scaled_changes_only_the_named_parameter():
    base = FiveBarParams()
    heavy = base.scaled("m3", 1.4)
    assert heavy.m3 == pytest.approx(0.2611 * 1.4, rel=1e-15)
    changed = [n for n in PARAM_NAMES if getattr(heavy, n) != getattr(base, n)]
    assert changed == ["m3"], f"scaled('m3', 1.4) changed {changed}"
    assert base.m3 == 0.2611, "scaled must not mutate the original"
    np.testing.assert_array_equal(FiveBar(heavy).packed, heavy.as_array(), err_msg="packed vector of the heavy plant")
    with pytest.raises(ValueError, match="m5"):
        base.scaled("m5", 2.0)
    with pytest.raises(ValueError, match=r"\bm3\b"):
        base.scaled("m3", -1.0)


def test_heavy_plant_is_heavier(plant, heavy_plant):
    """Adding mass to link 3 can only add kinetic energy: Dq(m3 x 1.4) - Dq is positive semidefinite
    (it is 0.4 m3 times link 3's CoM Jacobian Gram matrix), and strictly larger in some direction."""
    for point in GRID[::7]:
        theta = plant.inverse_kinematics(point)
        difference = heavy_plant.joint_inertia(theta) - plant.joint_inertia(theta)
        eigenvalues = np.linalg.eigvalsh(difference)
        # Dq entries are ~3e-2 kg m^2, rounded to ~1e-17: an eigenvalue above -1e-15 is "zero or
        # positive"; the added inertia 0.4 m3 |d c3 / d theta|^2 is ~1e-2 kg m^2, hence > 1e-4.
        assert eigenvalues.min() > -1e-15 and eigenvalues.max() > 1e-4, (
            f"Dq(m3 x 1.4) - Dq eigenvalues {eigenvalues} at P={point}")


@pytest.mark.parametrize("point", GRID[::3], ids=GRID_IDS[::3])
def test_heavy_plant_keeps_properties(heavy_plant, point):
    theta = heavy_plant.inverse_kinematics(point)
    check_spd("Dq (m3 x 1.4)", heavy_plant.joint_inertia(theta), f"P={point}")
    check_spd("D (m3 x 1.4)", heavy_plant.task_inertia(theta), f"P={point}")
    for dtheta in RATES[2:]:
        check_skew(heavy_plant, theta, dtheta, f"m3 x 1.4, P={point}, dtheta={dtheta}")


@pytest.mark.parametrize("model", ["fivebar", "serial2r"])
def test_regressor_times_base_parameters_is_the_inverse_dynamics(model):
    """Y(q, dq, dq_r, ddq_r) a = Dq ddq_r + Cq(q, dq) dq_r + G_q on random states of the working mode
    (the Slotine-Li parametrisation each plant provides); with dq_r = dq, ddq_r = ddq it is the
    plant's inverse dynamics. Tolerance: round-off of sums of terms of the size of the torque."""
    import importlib

    from ilcforce.plants import make_plant, params_class

    module = importlib.import_module(f"ilcforce.plants.{model}")
    rng = np.random.default_rng(3)
    for scale in (1.0, 1.4):  # the nominal and a perturbed plant: a follows the parameters
        params = params_class(model)().scaled("m2", scale)
        robot = make_plant(params)
        a = module.base_parameters(params)
        assert len(a) == len(module.BASE_PARAMETER_NAMES)
        for _ in range(20):
            q = robot.inverse_kinematics(np.array([0.2, 0.41]) + rng.uniform(-0.12, 0.12, 2) * [1.0, 0.2])
            dq, dq_r, ddq_r = rng.normal(0, 2, 2), rng.normal(0, 2, 2), rng.normal(0, 10, 2)
            Y = np.array(module.regressor(params.as_array(), *q, *dq, *dq_r, *ddq_r)).reshape(2, 6)
            assert np.all(Y[:, len(a):] == 0.0)
            want = robot.joint_inertia(q) @ ddq_r + robot.joint_coriolis(q, dq) @ dq_r + robot.gravity(q)
            np.testing.assert_allclose(Y[:, :len(a)] @ a, want, rtol=1e-12, atol=1e-13 * (1 + np.abs(want).max()),
                                       err_msg=f"{model}: Y a")
            np.testing.assert_allclose(
                np.array(module.regressor(params.as_array(), *q, *dq, *dq, *ddq_r)).reshape(2, 6)[:, :len(a)] @ a,
                robot.inverse_dynamics(q, dq, ddq_r), rtol=1e-12, atol=1e-13 * (1 + np.abs(want).max()),
                err_msg=f"{model}: Y a with dq_r = dq is the inverse dynamics")
