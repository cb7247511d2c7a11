"""The sampled-data simulator: one iteration of one controller on the true plant (SPEC sections 4-5).

Blocks and their doors (Drake style): the **plant** (``ilcforce.plant``) and the **wall**
(``ilcforce.task``) are integrated here with fixed-step RK4; the **controller** supplies only its
compiled law (``ilcforce.controllers.base``); this module holds the zero-order hold, the sensors,
the acceleration estimates, the watchdog and the logger. The plant never calls the controller and
the controller never integrates.

Per control sample k (t_k = k Ts), inside one compiled loop:

1. true plant terms at the sample: Dq^-1, Cq dtheta, J, dJ dtheta, contact force, disturbance;
2. measurements: angles, rates and force plus bounded noise; P, dP (and D, C if the law asks)
   from the *nominal* model at the measured state;
3. acceleration estimates (SPEC section 4):
   * ``implicit``: the law's torque is a polynomial of degree <= 2 in the force-axis acceleration
     a (eq. 14 is quadratic through Phi^T Gamma Phi sigma). The simulator evaluates the law at
     a = -1, 0, 1 m/s^2 (without writing memory), recovers tau(a) = tau0 + tau1 a + tau2 a^2 exactly,
     and solves a = p0 + q . tau(a), where p0 + q . tau is the true plant's force-axis acceleration
     for torque tau. Of the two roots it takes the one continuous with the linear case. Without a
     real root the previous sample's a is used and the event counted. dF and ddF follow from
     F = K_e (y - y_e) in contact.
   * ``filtered``: first-order low-pass filtered differences (cut-off ``filter_hz``) of the measured
     dP, of the measured force (-> dF) and of the filtered dF (-> ddF); a raw force is never
     differenced twice.
4. the law is evaluated once more with ``write=True`` (memory update) and its torque held for Ts;
5. watchdog: non-finite values, |tau| above ``torque_bound`` or a pose outside the working mode stop
   the iteration ("diverged"), recording the sample;
6. RK4 over Ts in ``substeps`` steps on the true plant, the disturbance evaluated at stage times.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, types

from ilcforce.controllers.base import (
    DIAG_SIGMA, DIAG_WIDTH, LAW_TYPE, MEAS_ACCEL, MEAS_DTHETA, MEAS_FORCE, MEAS_FORCE_ACCEL,
    MEAS_FORCE_RATE, MEAS_JACOBIAN, MEAS_POSITION, MEAS_TASK_CORIOLIS, MEAS_TASK_INERTIA,
    MEAS_THETA, MEAS_VELOCITY, MEAS_WIDTH, Controller,
)
from ilcforce.noise import IterationDraws, NoiseModel, disturbance
from ilcforce.plant import FiveBar, FiveBarParams, _accel_terms, _kinematics, _task_model
from ilcforce.records import LOG_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord
from ilcforce.task import REF_FORCE, REF_POSITION, Reference, Wall

ACCELERATION_SCHEMES = {"implicit": 0, "filtered": 1}

#: Watchdog outcomes of the compiled loop.
RUN_OK = 0
RUN_NONFINITE = 1
RUN_TORQUE_BOUND = 2
RUN_WORKING_MODE = 3
DIVERGENCE_REASONS = {
    RUN_NONFINITE: "a non-finite state or torque",
    RUN_TORQUE_BOUND: "|tau| above the torque bound",
    RUN_WORKING_MODE: "a pose outside the elbows-out working mode",
}

# Columns of the compiled loop's log array.
_LOG_COLUMNS = {
    "joint_angle": 0, "joint_rate": 2, "joint_angle_measured": 4, "joint_rate_measured": 6,
    "position": 8, "velocity": 10, "contact_force": 12, "contact_force_measured": 14,
    "disturbance": 16, "torque": 18, "task_input": 20, "sliding_surface": 22,
}
_LOG_WIDTH = 24

# Packed float settings: Ts, filter coefficient, torque bound, initial theta (2), initial dtheta (2)
_FS_TS, _FS_BETA, _FS_TAU_BOUND, _FS_THETA0, _FS_DTHETA0 = 0, 1, 2, 3, 5
# Packed integer settings
_IS_SUBSTEPS, _IS_LOG_EVERY, _IS_SCHEME, _IS_NOMINAL_DYNAMICS, _IS_FORCE_AXIS = 0, 1, 2, 3, 4

#: Probe accelerations (m/s^2) at which the implicit scheme samples the law.
_PROBE = 1.0
#: The implicit loop counts as having no solution when |d(loop residual)/da| at the root is below
#: this: the law then cancels the plant's own response (e.g. C1 with an exact model out of contact,
#: where D_nom S ddP cancels D ddP exactly) and any root is roundoff amplified by more than 1e6.
_DEGENERATE = 1e-6


@dataclass(frozen=True)
class SimulationSettings:
    """Sampling, integration, acceleration scheme and watchdog (SPEC sections 4 and 5)."""

    sample_time: float = 1e-4  # Ts, zero-order-hold control period, s
    substeps: int = 1  # RK4 steps per control period
    log_every: int = 10  # log every this many control samples (1 ms at the default Ts)
    acceleration: str = "implicit"  # "implicit" (resolve the algebraic loop) or "filtered"
    filter_hz: float = 50.0  # cut-off of the first-order filters of the "filtered" scheme, Hz
    torque_bound: float = 1e3  # watchdog bound on |tau|, N m
    initial_position: tuple[float, float] = (0.35, 0.40)  # P(0), at rest, m

    def __post_init__(self) -> None:
        if self.acceleration not in ACCELERATION_SCHEMES:
            raise ValueError(f"simulation.acceleration must be one of {', '.join(ACCELERATION_SCHEMES)}, "
                             f"got {self.acceleration!r}")
        for name in ("sample_time", "filter_hz", "torque_bound"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"simulation.{name} must be finite and positive, got {v!r}")
        for name in ("substeps", "log_every"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"simulation.{name} must be an integer >= 1, got {v!r}")

    def n_control(self, duration: float) -> int:
        """Number of control samples on [0, duration], both ends included."""
        steps = duration / self.sample_time
        n = int(round(steps))
        if n < 1 or abs(steps - n) > 1e-9 * max(1.0, steps):
            raise ValueError(f"simulation.sample_time = {self.sample_time:g} s does not divide the horizon "
                             f"reference.duration = {duration:g} s")
        return n + 1

    def n_log(self, duration: float) -> int:
        n = self.n_control(duration) - 1
        if n % self.log_every:
            raise ValueError(f"simulation.log_every = {self.log_every} does not divide the {n} control steps "
                             f"of the horizon")
        return n // self.log_every + 1


@njit(cache=True, error_model="numpy")
def _drift(p, th1, th2, d1, d2, ye, ke, w, fvx, fvy):
    """The true plant pressed against the wall, with the torque left out.

    Dq ddtheta = tau + r with r = J^T f - Cq dtheta, f the wall's reaction plus the disturbance
    (the force on the robot). Returns (ok, Px, Py, J00, J01, J10, J11, dJv_x, dJv_y, r1, r2,
    Mi00, Mi01, Mi11, F_y) with Mi = Dq^-1 and F_y the wall's force in the task.Wall convention.
    """
    (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, b1, b2, Mi00, Mi01, Mi11) = _accel_terms(p, th1, th2, d1, d2)
    pen = w * (py - ye)
    fy_wall = ke * pen if pen > 0.0 else 0.0
    gx = -fvx  # force on the robot: disturbance (eq. 1, tau_v = J^T F_v) ...
    gy = -w * fy_wall - fvy  # ... and the wall's reaction
    r1 = J00 * gx + J10 * gy - b1
    r2 = J01 * gx + J11 * gy - b2
    return (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, r1, r2, Mi00, Mi01, Mi11, fy_wall)


@njit(cache=True, error_model="numpy")
def _stage(p, th1, th2, d1, d2, tau1, tau2, ye, ke, w, fvx, fvy):
    """Joint accelerations of the true plant under torque tau. Returns (ok, dd1, dd2)."""
    (ok, _px, _py, _J00, _J01, _J10, _J11, _dx, _dy, r1, r2,
     Mi00, Mi01, Mi11, _fy) = _drift(p, th1, th2, d1, d2, ye, ke, w, fvx, fvy)
    q1 = tau1 + r1
    q2 = tau2 + r2
    return ok, Mi00 * q1 + Mi01 * q2, Mi01 * q1 + Mi11 * q2


@njit(cache=True, error_model="numpy")
def _set_candidate(meas, axis, a, dfdy):
    """Put a candidate force-axis acceleration a into the measurement vector (implicit scheme)."""
    meas[MEAS_ACCEL + axis] = a
    meas[MEAS_ACCEL + 1 - axis] = 0.0
    meas[MEAS_FORCE_ACCEL] = 0.0
    meas[MEAS_FORCE_ACCEL + 1] = dfdy * a if axis == 1 else 0.0


_SIM_SIGNATURE = types.UniTuple(types.int64, 3)(
    LAW_TYPE,
    types.float64[::1],  # true plant parameters
    types.float64[::1],  # nominal plant parameters
    types.float64[::1],  # wall: y_e, K_e, w
    types.float64[::1],  # law gains
    types.float64[:, ::1],  # mem_prev
    types.float64[:, ::1],  # mem_new
    types.float64[:, ::1],  # reference (n_control, 12)
    types.float64[:, ::1],  # disturbance on the half-step grid (2 substeps N + 1, 2)
    types.float64[:, ::1],  # sensor noise (n_control, 6)
    types.float64[::1],  # float settings
    types.int64[::1],  # integer settings
    types.float64[:, ::1],  # log output (n_log, _LOG_WIDTH), pre-filled with NaN
)


@njit(_SIM_SIGNATURE, cache=True, error_model="numpy")
def _simulate(law, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset, log):
    """One iteration. Returns (status, failing sample or -1, implicit-loop fallback count)."""
    n_steps = ref.shape[0] - 1
    ts = fset[_FS_TS]
    beta = fset[_FS_BETA]
    tau_bound = fset[_FS_TAU_BOUND]
    substeps = iset[_IS_SUBSTEPS]
    log_every = iset[_IS_LOG_EVERY]
    implicit = iset[_IS_SCHEME] == 0
    nominal_dyn = iset[_IS_NOMINAL_DYNAMICS] != 0
    fa = iset[_IS_FORCE_AXIS]
    ye, ke, w = wall[0], wall[1], wall[2]
    h = ts / substeps

    th1, th2 = fset[_FS_THETA0], fset[_FS_THETA0 + 1]
    d1, d2 = fset[_FS_DTHETA0], fset[_FS_DTHETA0 + 1]
    meas = np.zeros(MEAS_WIDTH)
    diag = np.zeros(DIAG_WIDTH)
    # filter states of the "filtered" scheme
    prev_vx = prev_vy = prev_fx = prev_fy = 0.0
    acc_x = acc_y = dfx = dfy = ddfx = ddfy = 0.0
    a_prev = 0.0
    fallback = 0

    for k in range(n_steps + 1):
        t = k * ts
        base = 2 * substeps * k
        fvx, fvy = dist[base, 0], dist[base, 1]
        # 1. true plant at the sample (reused as RK4's first stage)
        (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, r1, r2,
         Mi00, Mi01, Mi11, fy_wall) = _drift(p_true, th1, th2, d1, d2, ye, ke, w, fvx, fvy)
        if not ok:
            return RUN_WORKING_MODE, k, fallback
        a01 = Mi00 * r1 + Mi01 * r2  # joint acceleration at zero torque
        a02 = Mi01 * r1 + Mi11 * r2

        # 2. sensors, then the nominal model at the measured state
        tm1 = th1 + noise[k, 0]
        tm2 = th2 + noise[k, 1]
        dm1 = d1 + noise[k, 2]
        dm2 = d2 + noise[k, 3]
        fmx = noise[k, 4]  # the wall is frictionless: the true F_x is 0
        fmy = fy_wall + noise[k, 5]
        if nominal_dyn:
            (okn, pmx, pmy, vmx, vmy, N00, N01, N10, N11, D00, D01, D11,
             C00, C01, C10, C11) = _task_model(p_nom, tm1, tm2, dm1, dm2)
            meas[MEAS_TASK_INERTIA] = D00
            meas[MEAS_TASK_INERTIA + 1] = D01
            meas[MEAS_TASK_INERTIA + 2] = D11
            meas[MEAS_TASK_CORIOLIS] = C00
            meas[MEAS_TASK_CORIOLIS + 1] = C01
            meas[MEAS_TASK_CORIOLIS + 2] = C10
            meas[MEAS_TASK_CORIOLIS + 3] = C11
        else:
            (okn, pmx, pmy, _u3x, _u3y, _u4x, _u4y, _r00, _r01, _r10, _r11,
             N00, N01, N10, N11) = _kinematics(p_nom, tm1, tm2)
            vmx = N00 * dm1 + N01 * dm2
            vmy = N10 * dm1 + N11 * dm2
        if not okn:
            return RUN_WORKING_MODE, k, fallback
        meas[MEAS_THETA] = tm1
        meas[MEAS_THETA + 1] = tm2
        meas[MEAS_DTHETA] = dm1
        meas[MEAS_DTHETA + 1] = dm2
        meas[MEAS_FORCE] = fmx
        meas[MEAS_FORCE + 1] = fmy
        meas[MEAS_POSITION] = pmx
        meas[MEAS_POSITION + 1] = pmy
        meas[MEAS_VELOCITY] = vmx
        meas[MEAS_VELOCITY + 1] = vmy
        meas[MEAS_JACOBIAN] = N00
        meas[MEAS_JACOBIAN + 1] = N01
        meas[MEAS_JACOBIAN + 2] = N10
        meas[MEAS_JACOBIAN + 3] = N11

        # 3. acceleration estimates, 4. the law
        if implicit:
            dfdy = w * ke if w * (pmy - ye) > 0.0 else 0.0  # stiffness relation, in contact
            meas[MEAS_FORCE_RATE] = 0.0
            meas[MEAS_FORCE_RATE + 1] = dfdy * vmy
            # true force-axis acceleration for torque tau: p0 + q . tau
            if fa == 0:
                p0 = J00 * a01 + J01 * a02 + dJvx
                q1 = J00 * Mi00 + J01 * Mi01
                q2 = J00 * Mi01 + J01 * Mi11
            else:
                p0 = J10 * a01 + J11 * a02 + dJvy
                q1 = J10 * Mi00 + J11 * Mi01
                q2 = J10 * Mi01 + J11 * Mi11
            _set_candidate(meas, fa, 0.0, dfdy)
            t01, t02 = law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag)
            _set_candidate(meas, fa, _PROBE, dfdy)
            tp1, tp2 = law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag)
            _set_candidate(meas, fa, -_PROBE, dfdy)
            tn1, tn2 = law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag)
            # tau(a) = tau0 + tau1 a + tau2 a^2
            c1 = q1 * (tp1 - tn1) / (2.0 * _PROBE) + q2 * (tp2 - tn2) / (2.0 * _PROBE)
            c2 = (q1 * (tp1 + tn1 - 2.0 * t01) + q2 * (tp2 + tn2 - 2.0 * t02)) / (2.0 * _PROBE * _PROBE)
            c0 = p0 + q1 * t01 + q2 * t02
            # solve c2 a^2 + (c1 - 1) a + c0 = 0, the root continuous with c2 -> 0
            bb = c1 - 1.0
            disc = bb * bb - 4.0 * c2 * c0
            if disc < 0.0 or not math.isfinite(disc):
                a = a_prev
                fallback += 1
            else:
                den = bb + math.copysign(math.sqrt(disc), bb)
                if abs(den) < _DEGENERATE:
                    a = a_prev
                    fallback += 1
                else:
                    a = -2.0 * c0 / den
            a_prev = a
            _set_candidate(meas, fa, a, dfdy)
        else:
            if k == 0:
                prev_vx, prev_vy, prev_fx, prev_fy = vmx, vmy, fmx, fmy
            acc_x += beta * ((vmx - prev_vx) / ts - acc_x)
            acc_y += beta * ((vmy - prev_vy) / ts - acc_y)
            new_dfx = dfx + beta * ((fmx - prev_fx) / ts - dfx)
            new_dfy = dfy + beta * ((fmy - prev_fy) / ts - dfy)
            ddfx += beta * ((new_dfx - dfx) / ts - ddfx)  # difference of the filtered rate
            ddfy += beta * ((new_dfy - dfy) / ts - ddfy)
            dfx, dfy = new_dfx, new_dfy
            prev_vx, prev_vy, prev_fx, prev_fy = vmx, vmy, fmx, fmy
            meas[MEAS_ACCEL] = acc_x
            meas[MEAS_ACCEL + 1] = acc_y
            meas[MEAS_FORCE_RATE] = dfx
            meas[MEAS_FORCE_RATE + 1] = dfy
            meas[MEAS_FORCE_ACCEL] = ddfx
            meas[MEAS_FORCE_ACCEL + 1] = ddfy
        tau1, tau2 = law(k, t, meas, ref, gains, mem_prev, mem_new, True, diag)

        # 5. watchdog and log
        if not (math.isfinite(tau1) and math.isfinite(tau2)):
            return RUN_NONFINITE, k, fallback
        if abs(tau1) > tau_bound or abs(tau2) > tau_bound:
            return RUN_TORQUE_BOUND, k, fallback
        if k % log_every == 0:
            row = k // log_every
            det = J00 * J11 - J01 * J10
            log[row, 0] = th1
            log[row, 1] = th2
            log[row, 2] = d1
            log[row, 3] = d2
            log[row, 4] = tm1
            log[row, 5] = tm2
            log[row, 6] = dm1
            log[row, 7] = dm2
            log[row, 8] = px
            log[row, 9] = py
            log[row, 10] = J00 * d1 + J01 * d2
            log[row, 11] = J10 * d1 + J11 * d2
            log[row, 12] = 0.0
            log[row, 13] = fy_wall
            log[row, 14] = fmx
            log[row, 15] = fmy
            log[row, 16] = fvx
            log[row, 17] = fvy
            log[row, 18] = tau1
            log[row, 19] = tau2
            log[row, 20] = (J11 * tau1 - J10 * tau2) / det  # J^-T tau
            log[row, 21] = (-J01 * tau1 + J00 * tau2) / det
            log[row, 22] = diag[DIAG_SIGMA]
            log[row, 23] = diag[DIAG_SIGMA + 1]
        if k == n_steps:
            break

        # 6. RK4 on the true plant, torque held
        for i in range(substeps):
            m = base + 2 * i
            if i == 0:
                k1a = a01 + Mi00 * tau1 + Mi01 * tau2
                k1b = a02 + Mi01 * tau1 + Mi11 * tau2
            else:
                ok1, k1a, k1b = _stage(p_true, th1, th2, d1, d2, tau1, tau2, ye, ke, w, dist[m, 0], dist[m, 1])
                if not ok1:
                    return RUN_WORKING_MODE, k, fallback
            # stage velocities v2, v3, v4 (v1 = d)
            v2a, v2b = d1 + 0.5 * h * k1a, d2 + 0.5 * h * k1b
            ok2, k2a, k2b = _stage(p_true, th1 + 0.5 * h * d1, th2 + 0.5 * h * d2, v2a, v2b,
                                   tau1, tau2, ye, ke, w, dist[m + 1, 0], dist[m + 1, 1])
            v3a, v3b = d1 + 0.5 * h * k2a, d2 + 0.5 * h * k2b
            ok3, k3a, k3b = _stage(p_true, th1 + 0.5 * h * v2a, th2 + 0.5 * h * v2b, v3a, v3b,
                                   tau1, tau2, ye, ke, w, dist[m + 1, 0], dist[m + 1, 1])
            v4a, v4b = d1 + h * k3a, d2 + h * k3b
            ok4, k4a, k4b = _stage(p_true, th1 + h * v3a, th2 + h * v3b, v4a, v4b,
                                   tau1, tau2, ye, ke, w, dist[m + 2, 0], dist[m + 2, 1])
            if not (ok2 and ok3 and ok4):
                return RUN_WORKING_MODE, k, fallback
            th1 += h / 6.0 * (d1 + 2.0 * v2a + 2.0 * v3a + v4a)
            th2 += h / 6.0 * (d2 + 2.0 * v2b + 2.0 * v3b + v4b)
            d1 += h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a)
            d2 += h / 6.0 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
        if not (math.isfinite(th1) and math.isfinite(th2) and math.isfinite(d1) and math.isfinite(d2)):
            return RUN_NONFINITE, k + 1, fallback
    return RUN_OK, -1, fallback


@dataclass(frozen=True)
class IterationInputs:
    """Everything that defines one iteration apart from the controller.

    ``reference`` is the (n_control, 12) array of :meth:`ilcforce.task.Reference.sample`;
    ``draws`` the iteration's disturbance and sensor noise; ``selection`` the diagonal of S.
    """

    iteration: int
    true_plant: FiveBarParams
    nominal_plant: FiveBarParams
    wall: Wall
    reference: np.ndarray
    settings: SimulationSettings
    noise: NoiseModel
    draws: IterationDraws
    selection: tuple[float, float]


def force_axis(selection) -> int:
    """Index of the single force-controlled axis of S = diag(selection)."""
    s = [float(v) for v in selection]
    if sorted(s) != [0.0, 1.0]:
        raise ValueError(f"surface.selection must select exactly one force axis, e.g. [0, 1]; got {list(selection)}")
    return s.index(1.0)


def run_iteration(inputs: IterationInputs, controller: Controller, mem_prev: np.ndarray,
                  mem_new: np.ndarray) -> IterationRecord:
    """Simulate one iteration; the controller's memory buffers are read and written in place.

    Returns the :class:`~ilcforce.records.IterationRecord` without ``memory`` (the iteration loop
    attaches the controller's learned state) and with ``desired_torque`` left for the caller via
    :func:`desired_inputs` (it depends only on the true plant, so it is cached there).
    """
    s = inputs.settings
    ref = np.ascontiguousarray(inputs.reference, dtype=np.float64)
    n_control = ref.shape[0]
    n_log = (n_control - 1) // s.log_every + 1
    t_control = np.arange(n_control) * s.sample_time
    h = s.sample_time / s.substeps
    t_stage = np.arange(2 * s.substeps * (n_control - 1) + 1) * (0.5 * h)
    dist = np.ascontiguousarray(disturbance(t_stage, inputs.draws, inputs.noise))
    theta0 = FiveBar(inputs.true_plant).inverse_kinematics(s.initial_position)
    fset = np.array([s.sample_time, 1.0 - math.exp(-2.0 * math.pi * s.filter_hz * s.sample_time),
                     s.torque_bound, theta0[0], theta0[1], 0.0, 0.0])
    iset = np.array([s.substeps, s.log_every, ACCELERATION_SCHEMES[s.acceleration],
                     int(controller.uses_nominal_dynamics), force_axis(inputs.selection)], dtype=np.int64)
    wall = np.array([inputs.wall.position, inputs.wall.stiffness, inputs.wall.sign])
    log = np.full((n_log, _LOG_WIDTH), np.nan)
    status, k_fail, fallback = _simulate(
        controller.law, inputs.true_plant.as_array(), inputs.nominal_plant.as_array(), wall,
        np.ascontiguousarray(controller.gains(), dtype=np.float64), mem_prev, mem_new, ref, dist,
        np.ascontiguousarray(inputs.draws.sensor), fset, iset, log)

    signals = {"time": t_control[::s.log_every].copy()}
    for name, col in _LOG_COLUMNS.items():
        signals[name] = log[:, col:col + 2].copy()
    sel = np.asarray(inputs.selection, dtype=np.float64)
    ref_log = ref[::s.log_every]
    signals["position_error"] = (1.0 - sel) * (ref_log[:, REF_POSITION:REF_POSITION + 2] - signals["position"])  # eq. (6)
    signals["force_error"] = sel * (ref_log[:, REF_FORCE:REF_FORCE + 2] - signals["contact_force"])  # eq. (7)
    if status == RUN_OK:
        return IterationRecord(inputs.iteration, STATUS_COMPLETE, math.nan, "", int(fallback), signals)
    t_fail = float(t_control[min(k_fail, n_control - 1)])
    reason = f"{DIVERGENCE_REASONS[status]} at t = {t_fail:.4f} s"
    return IterationRecord(inputs.iteration, STATUS_DIVERGED, t_fail, reason, int(fallback), signals)


def desired_inputs(plant: FiveBarParams, wall: Wall, reference_log: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tau_d and J^-T tau_d along the desired motion (SPEC section 6, Table 3's H).

    tau_d = Dq ddtheta_d + Cq dtheta_d + J^T (w F_d) is the inverse dynamics (eq. 1) of ``plant``
    along P_d(t) = (x_d, y_e + w F_yd / K_e), including the desired contact force, so the wall's
    reaction -w F_d is balanced. ``reference_log`` is (n, 12); returns two (n, 2) arrays (N m, N).
    """
    robot = FiveBar(plant)
    n = reference_log.shape[0]
    tau_d = np.empty((n, 2))
    task_d = np.empty((n, 2))
    for i in range(n):
        pos = reference_log[i, 0:2]
        vel = reference_log[i, 2:4]
        acc = reference_log[i, 4:6]
        force = wall.sign * reference_log[i, 6:8]
        theta = robot.inverse_kinematics(pos)
        J = robot.jacobian(theta)
        dtheta = np.linalg.solve(J, vel)
        dJ = robot.jacobian_derivative(theta, dtheta)
        ddtheta = np.linalg.solve(J, acc - dJ @ dtheta)
        tau = robot.inverse_dynamics(theta, dtheta, ddtheta, force_on_end_effector=-force)
        tau_d[i] = tau
        task_d[i] = np.linalg.solve(J.T, tau)
    return tau_d, task_d


def complete_record(record: IterationRecord, desired: tuple[np.ndarray, np.ndarray], memory: dict,
                    memory_units: dict) -> IterationRecord:
    """Attach tau_d (NaN after a divergence, like the other logs) and the learned memory."""
    log = dict(record.log)
    valid = np.isfinite(log["torque"][:, :1])
    log["desired_torque"] = np.where(valid, desired[0], np.nan)
    log["desired_task_input"] = np.where(valid, desired[1], np.nan)
    missing = set(LOG_SIGNALS) - set(log)
    if missing:
        raise RuntimeError(f"record lacks log signals {sorted(missing)}")
    return IterationRecord(record.iteration, record.status, record.diverged_time, record.diverged_reason,
                           record.fallback_count, log, memory, memory_units)
