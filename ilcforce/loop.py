"""The compiled simulation loop (docs/model.md#acceleration, docs/model.md#sampling): one chunk of control samples of one iteration.

It calls the control law and the plant only through numba function pointers (``LAW_TYPE`` of
``ilcforce.controllers.base``, ``ACCEL_TYPE`` / ``KIN_TYPE`` / ``TASK_TYPE`` of
``ilcforce.plants.base``), so it is compiled once for every law and every plant, and it knows no
robot. The wall's contact law is ``ilcforce.task.wall_force`` (its one definition). See
``ilcforce.simulate`` for the steps of a control sample.

The loop runs control samples ``k_start .. k_stop - 1`` and keeps everything it carries from one
sample to the next (state, filter states, the previous implicit acceleration, counters) in the
``carry`` vector, so ``ilcforce.simulate.run_iteration`` can return to Python between chunks (to
honour Ctrl-C) and resume bit for bit.
"""

from __future__ import annotations

import math

import numpy as np

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import Sig, njit  # numba's, imported only when the loop runs through numba (ilcforce/compiled/jit.py)
from ilcforce.controllers.base import (
    DIAG_SIGMA, DIAG_WIDTH, MEAS_ACCEL, MEAS_DTHETA, MEAS_FORCE, MEAS_FORCE_ACCEL,
    MEAS_FORCE_RATE, MEAS_JACOBIAN, MEAS_POSITION, MEAS_TASK_CORIOLIS, MEAS_TASK_GRAVITY,
    MEAS_TASK_INERTIA, MEAS_THETA, MEAS_VELOCITY, MEAS_WIDTH, law_signature,
)
from ilcforce.plants.base import kernel_type
from ilcforce.task import wall_force, wall_stiffness

#: Watchdog outcomes of the compiled loop.
RUN_OK = 0
RUN_NONFINITE = 1
RUN_TORQUE_BOUND = 2
RUN_WORKING_MODE = 3
#: returned when the chunk ended at k_stop < the last sample: call again to continue
RUN_CONTINUE = 4

# Columns of the compiled loop's log array.
LOG_COLUMNS = {
    "joint_angle": 0, "joint_rate": 2, "joint_angle_measured": 4, "joint_rate_measured": 6,
    "position": 8, "velocity": 10, "contact_force": 12, "contact_force_measured": 14,
    "disturbance": 16, "torque": 18, "task_input": 20, "sliding_surface": 22,
}
LOG_FALLBACKS = 24  # implicit-scheme fallbacks in the log interval ending at the row's sample
LOG_WIDTH = 25

# Packed float settings: Ts, filter coefficient, torque bound
FS_TS, FS_BETA, FS_TAU_BOUND = 0, 1, 2
FS_WIDTH = 3
# Packed integer settings
IS_SUBSTEPS, IS_LOG_EVERY, IS_SCHEME, IS_NOMINAL_DYNAMICS, IS_FORCE_AXIS, IS_FALLBACK = 0, 1, 2, 3, 4, 5
IS_WIDTH = 6

# The carry vector: the state and everything the loop keeps between samples
CARRY_THETA, CARRY_DTHETA = 0, 2  # true joint angles and rates
CARRY_FILTER = 4  # prev_vx, prev_vy, prev_fx, prev_fy, acc_x, acc_y, dfx, dfy, ddfx, ddfy
CARRY_A_PREV = 14  # the implicit scheme's previous acceleration
CARRY_FALLBACK = 15  # implicit-loop fallback count so far
CARRY_FALLBACK_LOGGED = 16  # the count when the last log row was written
CARRY_WIDTH = 17

#: Probe accelerations (m/s^2) at which the implicit scheme samples the law.
_PROBE = 1.0
#: The implicit loop counts as having no solution when |d(loop residual)/da| at the root is below
#: this: the law then cancels the plant's own response (e.g. C1 with an exact model out of contact,
#: where D_nom S ddP cancels D ddP exactly) and any root is roundoff amplified by more than 1e6.
_DEGENERATE = 1e-6


def new_carry(theta0, dtheta0) -> np.ndarray:
    """The carry vector at k = 0: the initial state, filters and counters zero."""
    carry = np.zeros(CARRY_WIDTH)
    carry[CARRY_THETA:CARRY_THETA + 2] = theta0
    carry[CARRY_DTHETA:CARRY_DTHETA + 2] = dtheta0
    return carry


@njit(cache=True, error_model="numpy")
def _drift(accel, p, th1, th2, d1, d2, ye, ke, w, fvx, fvy):
    """The true plant pressed against the wall, with the torque left out.

    Dq ddtheta = tau + r with r = J^T f - Cq dtheta - G_q, f the wall's reaction plus the
    disturbance (the force on the robot). Returns (ok, Px, Py, J00, J01, J10, J11, dJv_x, dJv_y,
    r1, r2, Mi00, Mi01, Mi11, F_y) with Mi = Dq^-1 and F_y the wall's force in the task.Wall convention.
    """
    (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, b1, b2, Mi00, Mi01, Mi11) = accel(p, th1, th2, d1, d2)
    fy_wall = wall_force(py, ye, ke, w)
    gx = -fvx  # force on the robot: disturbance (eq. 1, tau_v = J^T F_v) ...
    gy = -w * fy_wall - fvy  # ... and the wall's reaction
    r1 = J00 * gx + J10 * gy - b1
    r2 = J01 * gx + J11 * gy - b2
    return (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, r1, r2, Mi00, Mi01, Mi11, fy_wall)


@njit(cache=True, error_model="numpy")
def _stage(accel, p, th1, th2, d1, d2, tau1, tau2, ye, ke, w, fvx, fvy):
    """Joint accelerations of the true plant under torque tau. Returns (ok, dd1, dd2)."""
    (ok, _px, _py, _J00, _J01, _J10, _J11, _dx, _dy, r1, r2,
     Mi00, Mi01, Mi11, _fy) = _drift(accel, p, th1, th2, d1, d2, ye, ke, w, fvx, fvy)
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


@njit(cache=True, error_model="numpy")
def _fallback(least_residual, a_prev, bb, c2):
    """The implicit scheme's acceleration where c2 a^2 + bb a + c0 = 0 has no usable root.

    "previous": the last sample's a. "least_residual": the minimiser of |c2 a^2 + bb a + c0|, the
    vertex -bb / (2 c2), which is the double root where the roots merge (continuous there); with no
    curvature to locate it (|c2| below _DEGENERATE, e.g. a law linear in a, where the residual is
    flat or the vertex is roundoff far away) the previous a.
    """
    if least_residual and abs(c2) > _DEGENERATE:
        a = -bb / (2.0 * c2)
        if math.isfinite(a):
            return a
    return a_prev


def _sim_signature():
    """The loop's numba signature (made when numba is imported)."""
    types = _jit.numba().types
    return types.UniTuple(types.int64, 2)(
        types.FunctionType(law_signature()),
        kernel_type("ACCEL"),  # true plant: forward dynamics terms
        kernel_type("KIN"),  # nominal plant: kinematics
        kernel_type("TASK"),  # nominal plant: task-space model
        types.intp,  # true plant parameters (address of the packed vector, see ilcforce.plants.base)
        types.intp,  # nominal plant parameters (address)
        types.float64[::1],  # wall: y_e, K_e, w
        types.float64[::1],  # law gains
        types.float64[:, ::1],  # mem_prev
        types.float64[:, ::1],  # mem_new
        types.float64[:, ::1],  # reference (n_control, 12)
        types.float64[:, ::1],  # disturbance on this chunk's half-step grid: stage indices 2 substeps k_start
        #                          .. 2 substeps min(k_stop, n_control - 1), i.e. the samples' times and RK4 stages
        types.float64[:, ::1],  # sensor noise (n_control, 6)
        types.float64[::1],  # float settings
        types.int64[::1],  # integer settings
        types.float64[:, ::1],  # log output (n_log, LOG_WIDTH), pre-filled with NaN
        types.float64[::1],  # carry (CARRY_WIDTH,), read at k_start and written back at the end
        types.int64,  # k_start
        types.int64,  # k_stop (exclusive; n_control ends the iteration)
    )


@njit(Sig(_sim_signature), cache=True, error_model="numpy", nogil=True)  # nogil: the store writes beside it (pipeline.py)
def _simulate(law, accel, kin, task, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset,
              iset, log, carry, k_start, k_stop):
    """Control samples k_start .. k_stop - 1 of one iteration.

    Returns (status, failing sample or -1); status RUN_CONTINUE when the chunk ended before the
    iteration did. The state and counters are read from and written back to ``carry``.
    """
    n_steps = ref.shape[0] - 1
    ts = fset[FS_TS]
    beta = fset[FS_BETA]
    tau_bound = fset[FS_TAU_BOUND]
    substeps = iset[IS_SUBSTEPS]
    log_every = iset[IS_LOG_EVERY]
    implicit = iset[IS_SCHEME] == 0
    nominal_dyn = iset[IS_NOMINAL_DYNAMICS] != 0
    fa = iset[IS_FORCE_AXIS]
    least_residual = iset[IS_FALLBACK] == 1
    ye, ke, w = wall[0], wall[1], wall[2]
    h = ts / substeps

    th1, th2 = carry[CARRY_THETA], carry[CARRY_THETA + 1]
    d1, d2 = carry[CARRY_DTHETA], carry[CARRY_DTHETA + 1]
    meas = np.zeros(MEAS_WIDTH)
    diag = np.zeros(DIAG_WIDTH)
    # filter states of the "filtered" scheme
    f0 = CARRY_FILTER
    prev_vx, prev_vy, prev_fx, prev_fy = carry[f0], carry[f0 + 1], carry[f0 + 2], carry[f0 + 3]
    acc_x, acc_y, dfx, dfy = carry[f0 + 4], carry[f0 + 5], carry[f0 + 6], carry[f0 + 7]
    ddfx, ddfy = carry[f0 + 8], carry[f0 + 9]
    a_prev = carry[CARRY_A_PREV]
    fallback = int(carry[CARRY_FALLBACK])
    fallback_logged = int(carry[CARRY_FALLBACK_LOGGED])
    status = RUN_CONTINUE
    k_fail = -1

    for k in range(k_start, min(k_stop, n_steps + 1)):
        t = k * ts
        base = 2 * substeps * (k - k_start)  # this sample's row of the chunk's disturbance
        fvx, fvy = dist[base, 0], dist[base, 1]
        # 1. true plant at the sample (reused as RK4's first stage)
        (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, r1, r2,
         Mi00, Mi01, Mi11, fy_wall) = _drift(accel, p_true, th1, th2, d1, d2, ye, ke, w, fvx, fvy)
        if not ok:
            status, k_fail = RUN_WORKING_MODE, k
            break
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
             C00, C01, C10, C11, Gx, Gy) = task(p_nom, tm1, tm2, dm1, dm2)
            meas[MEAS_TASK_INERTIA] = D00
            meas[MEAS_TASK_INERTIA + 1] = D01
            meas[MEAS_TASK_INERTIA + 2] = D11
            meas[MEAS_TASK_CORIOLIS] = C00
            meas[MEAS_TASK_CORIOLIS + 1] = C01
            meas[MEAS_TASK_CORIOLIS + 2] = C10
            meas[MEAS_TASK_CORIOLIS + 3] = C11
            meas[MEAS_TASK_GRAVITY] = Gx
            meas[MEAS_TASK_GRAVITY + 1] = Gy
        else:
            (okn, pmx, pmy, N00, N01, N10, N11) = kin(p_nom, tm1, tm2)
            vmx = N00 * dm1 + N01 * dm2
            vmy = N10 * dm1 + N11 * dm2
        if not okn:
            status, k_fail = RUN_WORKING_MODE, k
            break
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
            dfdy = wall_stiffness(pmy, vmy, ye, ke, w)  # stiffness relation, in contact
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
                a = _fallback(least_residual, a_prev, bb, c2)
                fallback += 1
            else:
                den = bb + math.copysign(math.sqrt(disc), bb)
                if abs(den) < _DEGENERATE:
                    a = _fallback(least_residual, a_prev, bb, c2)
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
            status, k_fail = RUN_NONFINITE, k
            break
        if abs(tau1) > tau_bound or abs(tau2) > tau_bound:
            status, k_fail = RUN_TORQUE_BOUND, k
            break
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
            log[row, LOG_FALLBACKS] = fallback - fallback_logged
            fallback_logged = fallback
        if k == n_steps:
            status = RUN_OK
            break

        # 6. RK4 on the true plant, torque held
        ok1 = 1.0
        for i in range(substeps):
            m = base + 2 * i
            if i == 0:
                k1a = a01 + Mi00 * tau1 + Mi01 * tau2
                k1b = a02 + Mi01 * tau1 + Mi11 * tau2
            else:
                ok1, k1a, k1b = _stage(accel, p_true, th1, th2, d1, d2, tau1, tau2, ye, ke, w,
                                       dist[m, 0], dist[m, 1])
                if not ok1:
                    break
            # stage velocities v2, v3, v4 (v1 = d)
            v2a, v2b = d1 + 0.5 * h * k1a, d2 + 0.5 * h * k1b
            ok2, k2a, k2b = _stage(accel, p_true, th1 + 0.5 * h * d1, th2 + 0.5 * h * d2, v2a, v2b,
                                   tau1, tau2, ye, ke, w, dist[m + 1, 0], dist[m + 1, 1])
            v3a, v3b = d1 + 0.5 * h * k2a, d2 + 0.5 * h * k2b
            ok3, k3a, k3b = _stage(accel, p_true, th1 + 0.5 * h * v2a, th2 + 0.5 * h * v2b, v3a, v3b,
                                   tau1, tau2, ye, ke, w, dist[m + 1, 0], dist[m + 1, 1])
            v4a, v4b = d1 + h * k3a, d2 + h * k3b
            ok4, k4a, k4b = _stage(accel, p_true, th1 + h * v3a, th2 + h * v3b, v4a, v4b,
                                   tau1, tau2, ye, ke, w, dist[m + 2, 0], dist[m + 2, 1])
            if not (ok2 and ok3 and ok4):
                ok1 = 0.0
                break
            th1 += h / 6.0 * (d1 + 2.0 * v2a + 2.0 * v3a + v4a)
            th2 += h / 6.0 * (d2 + 2.0 * v2b + 2.0 * v3b + v4b)
            d1 += h / 6.0 * (k1a + 2.0 * k2a + 2.0 * k3a + k4a)
            d2 += h / 6.0 * (k1b + 2.0 * k2b + 2.0 * k3b + k4b)
        if not ok1:
            status, k_fail = RUN_WORKING_MODE, k
            break
        if not (math.isfinite(th1) and math.isfinite(th2) and math.isfinite(d1) and math.isfinite(d2)):
            status, k_fail = RUN_NONFINITE, k + 1
            break

    if status != RUN_OK and status != RUN_CONTINUE and fallback > fallback_logged:
        # a divergence: the fallbacks since the last log row go to the row whose interval holds k_fail
        row = min((k_fail + log_every - 1) // log_every, log.shape[0] - 1)
        log[row, LOG_FALLBACKS] = fallback - fallback_logged
        fallback_logged = fallback
    carry[CARRY_THETA], carry[CARRY_THETA + 1] = th1, th2
    carry[CARRY_DTHETA], carry[CARRY_DTHETA + 1] = d1, d2
    carry[f0], carry[f0 + 1], carry[f0 + 2], carry[f0 + 3] = prev_vx, prev_vy, prev_fx, prev_fy
    carry[f0 + 4], carry[f0 + 5], carry[f0 + 6], carry[f0 + 7] = acc_x, acc_y, dfx, dfy
    carry[f0 + 8], carry[f0 + 9] = ddfx, ddfy
    carry[CARRY_A_PREV] = a_prev
    carry[CARRY_FALLBACK] = fallback
    carry[CARRY_FALLBACK_LOGGED] = fallback_logged
    return status, k_fail
