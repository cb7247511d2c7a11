"""The compiled simulation loop (docs/model.md#acceleration, docs/model.md#sampling, docs/model.md#n-dof): one
chunk of control samples of one iteration, for every robot.

The steps of a control sample are described in ``ilcforce.simulate``: the true plant at the sample, the
sensors and the nominal model, the acceleration estimate (implicit or filtered), the law, the watchdog and
the log, then RK4 with the torque held. Every quantity is an n-vector or an n x n matrix (n the task's axes,
the plant's joints). The loop calls the plant only through one kernel (``nd_dyn`` of ``ilcforce.plants.nd``:
position, Jacobian, and at higher levels dJ dq, M, C dq + g, C, g, dJ) and the law only through the
signature of ``ilcforce.controllers.nd``, both numba function pointers, so it knows no robot and no method.
The wall's contact law is ``ilcforce.task.wall_force`` (its one definition), with friction in the wall's plane;
the force sensor reads its normal component (``ilcforce.ndof.sensing.sense_force``).

The task frame is the wall's (docs/model.md#wall-plane): X = R P with R's rows the frame's axes, the
wall's normal among them at the force axis, so J_X = R J and the contact force acts along that axis.
The planar robots' tasks are R = I.

Layouts, in blocks n wide: ``carry`` (7 n + 3: state, filter states, the previous implicit acceleration,
counters), the log (12 n + 1 columns, see :func:`log_columns`), the sensor noise (3 n: angles, rates,
force), the disturbance (n, task frame). The loop runs control samples ``k_start .. k_stop - 1`` and keeps
what it carries from one sample to the next in ``carry``, so ``ilcforce.simulate.run_iteration`` can return
to Python between chunks (to honour Ctrl-C) and resume bit for bit.

Speed: the chunk works on views without an owner (``ilcforce.compiled.views``: no reference counting in
the hot path), and it is compiled once per task dimension with n a number (:func:`simulate_2`,
:func:`simulate_3`; any other n through :func:`simulate_any`; :func:`simulator` compiles the one a run needs), so
that the loops over the axes are unrolled.
One source for every n; docs/design.md has the figures.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import (
    M_ACCEL, M_FORCE_ACCEL, M_FORCE_RATE, M_VELOCITY, M_WIDTH,
    at, at_py, law_signature,
)
from ilcforce.compiled.dense import cholesky_solve, lu, lu_solve_transposed
from ilcforce.compiled.views import carve, unowned, unowned_matrix
from ilcforce.ndof.contact import drift as _drift, stage as _stage
from ilcforce.ndof.sensing import filtered_estimates, measure, sense_force, sense_joints
from ilcforce.plants.nd import nd_type
from ilcforce.task import wall_stiffness

RUN_OK, RUN_NONFINITE, RUN_TORQUE_BOUND, RUN_WORKING_MODE, RUN_CONTINUE = 0, 1, 2, 3, 4

FS_TS, FS_BETA, FS_TAU_BOUND = 0, 1, 2
IS_SUBSTEPS, IS_LOG_EVERY, IS_SCHEME, IS_NOMINAL_DYNAMICS, IS_FORCE_AXIS, IS_FALLBACK = 0, 1, 2, 3, 4, 5
IS_WIDTH_TRUE, IS_WIDTH_NOMINAL = 6, 7  # the plants' kernel buffers (ilcforce.plants.nd.nd_width)
IS_LAW_SCRATCH = 8  # the law's scratch after its diag entries (a controller's nd_scratch, 0 for most)
IS_WIDTH = 9

#: the log's signals in column-block order (block b starts at column b n)
LOG_BLOCKS = ("joint_angle", "joint_rate", "joint_angle_measured", "joint_rate_measured", "position", "velocity",
              "contact_force", "contact_force_measured", "disturbance", "torque", "task_input", "sliding_surface")


def log_columns(n: int) -> dict[str, int]:
    return {name: b * n for b, name in enumerate(LOG_BLOCKS)}


def log_fallbacks(n: int) -> int:
    return len(LOG_BLOCKS) * n


def log_width(n: int) -> int:
    return len(LOG_BLOCKS) * n + 1


def carry_width(n: int) -> int:
    return 7 * n + 3


def carry_fallback(n: int) -> int:
    return 7 * n + 1


#: the loop's scratch vectors (n entries each) and matrices (n x n), carved from one buffer per chunk: the counts of
#: the `carve(work, o, n)` and `carve(work, o, nn)` lines of `_chunk`; a miscount stops every run at its first chunk
_SCRATCH_VECTORS, _SCRATCH_MATRICES = 29, 8


def work_width(n: int, iset) -> int:
    """The floats of the loop's scratch buffer ``work`` for a task of n axes and the integer settings ``iset``:
    the plants' kernel buffers, the measurement vector, the law's diag and scratch, then the loop's own vectors
    and matrices. The caller makes it and holds it for the call: the loop's scratch arrays are views of it
    without an owner (``ilcforce.compiled.views``), valid only while it lives."""
    return (int(iset[IS_WIDTH_TRUE]) + int(iset[IS_WIDTH_NOMINAL]) + at_py(M_WIDTH, n) + 4 * n
            + int(iset[IS_LAW_SCRATCH]) + _SCRATCH_VECTORS * n + _SCRATCH_MATRICES * n * n)


def new_carry(theta0, dtheta0) -> np.ndarray:
    """The carry at k = 0: state, filters zero (prev_v, prev_f, acc, dF, ddF: n each), a_prev, counters."""
    n = len(theta0)
    carry = np.zeros(carry_width(n))
    carry[:n] = theta0
    carry[n:2 * n] = dtheta0
    return carry


#: Probe accelerations (m/s^2) at which the implicit scheme samples the law.
_PROBE = 1.0
#: The implicit loop counts as having no solution when |d(loop residual)/da| at the root is below
#: this: the law then cancels the plant's own response (e.g. C1 with an exact model out of contact,
#: where D_nom S ddP cancels D ddP exactly) and any root is roundoff amplified by more than 1e6.
_DEGENERATE = 1e-6


def _sim_signature():
    types = _jit.numba().types
    return types.UniTuple(types.int64, 2)(
        types.FunctionType(law_signature()),
        nd_type(),  # true plant
        nd_type(),  # nominal plant
        types.intp, types.intp,  # their packed parameters (addresses)
        types.float64[::1],  # wall (ilcforce.task.Wall.packed): y_e, K_e, w, R (n x n, row-major), D_e, mu, v_eps
        types.float64[::1],  # gains
        types.float64[:, ::1], types.float64[:, ::1],  # mem_prev, mem_new
        types.float64[:, ::1],  # reference (n_control, 6 n)
        types.float64[:, ::1],  # disturbance (task frame, n columns) on the chunk's half-step grid
        types.float64[:, ::1],  # sensor noise (n_control, 3 n)
        types.float64[::1], types.int64[::1],  # float and integer settings
        types.float64[:, ::1],  # log (n_log, 12 n + 1)
        types.float64[::1],  # carry (7 n + 3)
        types.float64[::1],  # work: the scratch buffer, work_width floats, the caller's (held for the call)
        types.int64, types.int64,  # k_start, k_stop
    )


@njit(cache=True, error_model="numpy", inline="always")
def _chunk(n, law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset,
           log, carry, work, k_start, k_stop):
    """Control samples k_start .. k_stop - 1 of one iteration of a task of n axes; (status, failing sample or
    -1). Inlined into each entry below, which gives n: a number there, so that numba compiles the loops over
    the axes for that n."""
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
    nn = n * n

    # the scratch, carved from the caller's buffer ``work`` (which the caller holds for the call: a buffer made
    # here would be freed after its last use, under the views), and every array as a view without an owner
    # (ilcforce.compiled.views): no reference counting in the hot path
    for i in range(work.shape[0]):  # the scratch starts each chunk at zero, as a fresh allocation would
        work[i] = 0.0
    o = 0
    wall = unowned(wall)
    gains = unowned(gains)
    fset = unowned(fset)
    carry = unowned(carry)
    mem_prev = unowned_matrix(mem_prev)
    mem_new = unowned_matrix(mem_new)
    ref = unowned_matrix(ref)
    dist = unowned_matrix(dist)
    noise = unowned_matrix(noise)
    log = unowned_matrix(log)
    out_t, o = carve(work, o, iset[IS_WIDTH_TRUE])
    out_n, o = carve(work, o, iset[IS_WIDTH_NOMINAL])
    meas, o = carve(work, o, at(M_WIDTH, n))
    diag, o = carve(work, o, 4 * n + iset[IS_LAW_SCRATCH])  # controllers.nd.diag_width, then the law's scratch
    X, o = carve(work, o, n)
    JX, o = carve(work, o, nn)
    dJv, o = carve(work, o, n)
    r, o = carve(work, o, n)
    L, o = carve(work, o, nn)
    a0, o = carve(work, o, n)  # joint acceleration at zero torque
    Xs, o = carve(work, o, n)
    JXs, o = carve(work, o, nn)
    dJvs, o = carve(work, o, n)
    rs, o = carve(work, o, n)
    Ls, o = carve(work, o, nn)
    tau, o = carve(work, o, n)
    t0, o = carve(work, o, n)
    tp, o = carve(work, o, n)
    tn, o = carve(work, o, n)
    qrow, o = carve(work, o, n)
    qm, o = carve(work, o, n)
    dqm, o = carve(work, o, n)
    DJ, o = carve(work, o, nn)
    LU, o = carve(work, o, nn)
    piv, o = carve(work, o, n)
    Ji, o = carve(work, o, nn)  # J_X^-1
    tmp, o = carve(work, o, nn)
    col, o = carve(work, o, n)
    th, o = carve(work, o, n)
    d, o = carve(work, o, n)
    qs, o = carve(work, o, n)
    k1, o = carve(work, o, n)
    k2, o = carve(work, o, n)
    k3, o = carve(work, o, n)
    k4, o = carve(work, o, n)
    v2, o = carve(work, o, n)
    v3, o = carve(work, o, n)
    v4, o = carve(work, o, n)
    fmeas, o = carve(work, o, n)
    fc, o = carve(work, o, n)  # the true contact force in the task frame at the sample (the log's)
    fcs, o = carve(work, o, n)  # an RK4 stage's contact-force scratch (the friction's, ilcforce.ndof.contact.drift)
    if o != work.shape[0]:  # before any write: a buffer of another size than work_width's is the caller's bug
        raise ValueError("the loop's scratch buffer is not the size work_width gives")

    for i in range(n):
        th[i] = carry[i]
        d[i] = carry[n + i]
    f0 = 2 * n  # filters: prev_v, prev_f, acc, dF, ddF (n each)
    a_prev = carry[7 * n]
    fallback = int(carry[7 * n + 1])
    fallback_logged = int(carry[7 * n + 2])
    status = RUN_CONTINUE
    k_fail = -1
    cols = n  # column blocks of the log are n wide

    for k in range(k_start, min(k_stop, n_steps + 1)):
        t = k * ts
        base = 2 * substeps * (k - k_start)
        # 1. true plant at the sample (reused as RK4's first stage)
        ok, _f_normal = _drift(dyn_true, p_true, th, d, wall, fa, dist[base], out_t, X, JX, dJv, r, L, fc, True)
        if not ok:
            status, k_fail = RUN_WORKING_MODE, k
            break
        for j in range(n):
            a0[j] = r[j]
        cholesky_solve(n, L, a0, a0)

        # 2. sensors, then the nominal model at the measured state
        sense_joints(n, k, th, d, noise, qm, dqm)
        sense_force(n, k, fa, fc, noise, fmeas)  # the normal force, not the friction (ilcforce.ndof.sensing)
        if not measure(n, dyn_nom, p_nom, wall, qm, dqm, fmeas, 2 if nominal_dyn else 0, out_n, Xs, JXs, dJvs, DJ,
                       LU, piv, col, Ji, tmp, meas):
            status, k_fail = RUN_WORKING_MODE, k
            break

        # 3. acceleration estimates, 4. the law
        A0 = at(M_ACCEL, n)
        FR0 = at(M_FORCE_RATE, n)
        FA0 = at(M_FORCE_ACCEL, n)
        if implicit:
            vfa = meas[at(M_VELOCITY, n) + fa]
            dfdy = wall_stiffness(Xs[fa], vfa, ye, ke, w)
            for i in range(n):
                meas[FR0 + i] = dfdy * vfa if i == fa else 0.0
            # true force-axis acceleration for torque tau: p0 + q . tau, q = M^-1 J_X[fa]^T
            p0 = 0.0
            for j in range(n):
                p0 += JX[fa * n + j] * a0[j]
            p0 += dJv[fa]
            for j in range(n):
                qrow[j] = JX[fa * n + j]
            cholesky_solve(n, L, qrow, qrow)
            for i in range(n):
                meas[A0 + i] = 0.0
                meas[FA0 + i] = 0.0
            law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag, t0)
            meas[A0 + fa] = _PROBE
            meas[FA0 + fa] = dfdy * _PROBE
            law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag, tp)
            meas[A0 + fa] = -_PROBE
            meas[FA0 + fa] = -dfdy * _PROBE
            law(k, t, meas, ref, gains, mem_prev, mem_new, False, diag, tn)
            c1 = 0.0
            c2 = 0.0
            c0 = p0
            for j in range(n):
                c1 += qrow[j] * (tp[j] - tn[j]) / (2.0 * _PROBE)
                c2 += qrow[j] * (tp[j] + tn[j] - 2.0 * t0[j])
                c0 += qrow[j] * t0[j]
            c2 = c2 / (2.0 * _PROBE * _PROBE)
            bb = c1 - 1.0
            disc = bb * bb - 4.0 * c2 * c0
            a = 0.0
            use_fallback = False
            if disc < 0.0 or not math.isfinite(disc):
                use_fallback = True
            else:
                den = bb + math.copysign(math.sqrt(disc), bb)
                if abs(den) < _DEGENERATE:
                    use_fallback = True
                else:
                    a = -2.0 * c0 / den
            if use_fallback:
                a = a_prev
                if least_residual and abs(c2) > _DEGENERATE:
                    v = -bb / (2.0 * c2)
                    if math.isfinite(v):
                        a = v
                fallback += 1
            a_prev = a
            meas[A0 + fa] = a
            meas[FA0 + fa] = dfdy * a
        else:
            filtered_estimates(n, k, ts, beta, meas, fmeas, carry, f0)
        law(k, t, meas, ref, gains, mem_prev, mem_new, True, diag, tau)

        # 5. watchdog and log
        bad = False
        over = False
        for j in range(n):
            if not math.isfinite(tau[j]):
                bad = True
            elif abs(tau[j]) > tau_bound:
                over = True
        if bad:
            status, k_fail = RUN_NONFINITE, k
            break
        if over:
            status, k_fail = RUN_TORQUE_BOUND, k
            break
        if k % log_every == 0:
            row = k // log_every
            for j in range(n):
                log[row, j] = th[j]
                log[row, cols + j] = d[j]
                log[row, 2 * cols + j] = qm[j]
                log[row, 3 * cols + j] = dqm[j]
                log[row, 9 * cols + j] = tau[j]
                col[j] = tau[j]
            for i in range(n):
                log[row, 4 * cols + i] = X[i]
                s = 0.0
                for j in range(n):
                    s += JX[i * n + j] * d[j]
                log[row, 5 * cols + i] = s
                log[row, 6 * cols + i] = fc[i]
                log[row, 7 * cols + i] = fmeas[i]
                log[row, 8 * cols + i] = dist[base, i]
                log[row, 11 * cols + i] = diag[i]
            # J_X^-T tau at the true pose
            if lu(n, JX, 0, LU, piv):
                lu_solve_transposed(n, LU, piv, col)
                for i in range(n):
                    log[row, 10 * cols + i] = col[i]
            else:
                for i in range(n):
                    log[row, 10 * cols + i] = math.nan
            log[row, 12 * cols] = fallback - fallback_logged
            fallback_logged = fallback
        if k == n_steps:
            status = RUN_OK
            break

        # 6. RK4 on the true plant, torque held
        ok1 = True
        for st in range(substeps):
            m = base + 2 * st
            if st == 0:
                for j in range(n):
                    k1[j] = tau[j] + r[j]
                cholesky_solve(n, L, k1, k1)
            else:
                ok1 = _stage(dyn_true, p_true, th, d, tau, wall, fa, dist[m], out_t, Xs, JXs, dJvs, rs, Ls, fcs, k1)
                if not ok1:
                    break
            for j in range(n):
                v2[j] = d[j] + 0.5 * h * k1[j]
                qs[j] = th[j] + 0.5 * h * d[j]
            ok2 = _stage(dyn_true, p_true, qs, v2, tau, wall, fa, dist[m + 1], out_t, Xs, JXs, dJvs, rs, Ls, fcs, k2)
            for j in range(n):
                v3[j] = d[j] + 0.5 * h * k2[j]
                qs[j] = th[j] + 0.5 * h * v2[j]
            ok3 = ok2 and _stage(dyn_true, p_true, qs, v3, tau, wall, fa, dist[m + 1], out_t, Xs, JXs, dJvs, rs,
                                 Ls, fcs, k3)
            for j in range(n):
                v4[j] = d[j] + h * k3[j]
                qs[j] = th[j] + h * v3[j]
            ok4 = ok3 and _stage(dyn_true, p_true, qs, v4, tau, wall, fa, dist[m + 2], out_t, Xs, JXs, dJvs, rs,
                                 Ls, fcs, k4)
            if not ok4:
                ok1 = False
                break
            for j in range(n):
                th[j] += h / 6.0 * (d[j] + 2.0 * v2[j] + 2.0 * v3[j] + v4[j])
                d[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
        if not ok1:
            status, k_fail = RUN_WORKING_MODE, k
            break
        finite = True
        for j in range(n):
            if not (math.isfinite(th[j]) and math.isfinite(d[j])):
                finite = False
        if not finite:
            status, k_fail = RUN_NONFINITE, k + 1
            break

    if status != RUN_OK and status != RUN_CONTINUE and fallback > fallback_logged:
        row = min((k_fail + log_every - 1) // log_every, log.shape[0] - 1)
        log[row, 12 * cols] = fallback - fallback_logged
        fallback_logged = fallback
    for i in range(n):
        carry[i] = th[i]
        carry[n + i] = d[i]
    carry[7 * n] = a_prev
    carry[7 * n + 1] = fallback
    carry[7 * n + 2] = fallback_logged
    return status, k_fail


def simulate_2(law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset,
               log, carry, work, k_start, k_stop):
    """:func:`_chunk` for a task of 2 axes (the planar robots)."""
    return _chunk(2, law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset,
                  iset, log, carry, work, k_start, k_stop)


def simulate_3(law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset, iset,
               log, carry, work, k_start, k_stop):
    """:func:`_chunk` for a task of 3 axes (the spatial arm)."""
    return _chunk(3, law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset,
                  iset, log, carry, work, k_start, k_stop)


def simulate_any(law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new, ref, dist, noise, fset,
                 iset, log, carry, work, k_start, k_stop):
    """:func:`_chunk` for a task of any number of axes, read from the carry's length (7 n + 3)."""
    return _chunk((carry.shape[0] - 3) // 7, law, dyn_true, dyn_nom, p_true, p_nom, wall, gains, mem_prev, mem_new,
                  ref, dist, noise, fset, iset, log, carry, work, k_start, k_stop)


#: the entry for each task dimension it names; any other runs through :func:`simulate_any`
ENTRIES = {2: simulate_2, 3: simulate_3}


@functools.cache
def _compiled(entry):
    """``entry`` compiled (or loaded from numba's cache) with the loop's signature, on first request: numba
    compiles a function with an explicit signature when it is made, so the entries are made only when a run
    needs one (each holds the whole loop; all three together took a first run about 2.5 minutes)."""
    return _jit.numba().njit(_sim_signature(), cache=True, error_model="numpy", nogil=True)(entry)  # nogil: the
    # store writes beside it (pipeline.py)


def simulator(n: int):
    """The compiled loop for a task of ``n`` axes (one of the entries above: the same code and numbers)."""
    return _compiled(ENTRIES.get(int(n), simulate_any))


def simulator_any():
    """The compiled loop that reads n from the carry, for any n (what :func:`simulator` gives for an n without an
    entry of its own)."""
    return _compiled(simulate_any)
