"""What a controller measures at a control sample, in n dimensions (docs/model.md#acceleration,
docs/model.md#n-dof): the sensors, the nominal model at the measured state and the filtered estimates, into the
law's measurement vector. The loop (``ilcforce.loop``) and the MuJoCo cross-check's sampler
(``ilcforce.crosscheck.sample``) both call these, so the two plants are sensed by the same code.
"""

from __future__ import annotations

from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import (
    M_ACCEL, M_DTHETA, M_FORCE, M_FORCE_ACCEL, M_FORCE_RATE, M_JACOBIAN, M_POSITION, M_THETA, M_VELOCITY, at,
)
from ilcforce.ndof.algebra import task_model
from ilcforce.ndof.contact import to_task

__all__ = ["sense_joints", "sense_force", "measure", "filtered_estimates"]


@njit(cache=True, error_model="numpy", inline="always")
def sense_joints(n, k, th, d, noise, qm, dqm):
    """The measured angles and rates: the state plus the sample's encoder and rate-sensor noise."""
    for j in range(n):
        qm[j] = th[j] + noise[k, j]
        dqm[j] = d[j] + noise[k, n + j]


@njit(cache=True, error_model="numpy", inline="always")
def sense_force(n, k, fa, force, noise, fmeas):
    """The force sensor's reading (docs/model.md#wall): the true contact force's normal component ``force[fa]``
    (the wall's spring and damper together, what a load cell between tool and wall feels) plus the sample's
    sensor noise on every axis; the in-plane axes read noise alone. A one-axis sensor along the wall's normal, as
    the paper's F = (0, F_y): the friction in the plane is not measured, so the laws' feed-forward w F does not
    cancel it and it acts on the position loop as an unmeasured disturbance."""
    for i in range(n):
        fmeas[i] = (force[fa] if i == fa else 0.0) + noise[k, 2 * n + i]


@njit(cache=True, error_model="numpy", inline="always")
def measure(n, dyn_nom, p_nom, wall, qm, dqm, fmeas, level, out_n, Xs, JXs, dJvs, DJ, LU, piv, col, Ji, tmp,
            meas):
    """The nominal model at the measured state (kernel ``level``: 0 kinematics, 2 with eq. (4)'s D, C, G) into
    ``meas`` with the measured angles, rates and force; False if the nominal kernel or J_X^-1 finds the pose
    outside the working mode. The others are scratch."""
    if dyn_nom(p_nom, qm, dqm, level, out_n) == 0.0:
        return False
    to_task(n, wall, out_n, Xs, JXs, dJvs, DJ, level)
    P0 = at(M_POSITION, n)
    J0 = at(M_JACOBIAN, n)
    for i in range(n):
        meas[P0 + i] = Xs[i]
        s = 0.0
        for j in range(n):
            meas[J0 + i * n + j] = JXs[i * n + j]
            s += JXs[i * n + j] * dqm[j]
        meas[at(M_VELOCITY, n) + i] = s
        meas[at(M_THETA, n) + i] = qm[i]
        meas[at(M_DTHETA, n) + i] = dqm[i]
        meas[at(M_FORCE, n) + i] = fmeas[i]
    if level == 2 and not task_model(n, out_n, JXs, DJ, LU, piv, col, Ji, tmp, meas):  # eq. (4)
        return False
    return True


@njit(cache=True, error_model="numpy", inline="always")
def filtered_estimates(n, k, ts, beta, meas, fmeas, filters, f0):
    """The "filtered" scheme's estimates (docs/model.md#acceleration) into ``meas``: first-order low-pass
    filtered differences of the measured velocity (-> acceleration), of the measured force (-> dF) and of the
    filtered dF (-> ddF). ``filters[f0:]`` holds their states (previous velocity, previous force, acceleration,
    dF, ddF: n each), started at the first sample's values at k = 0."""
    A0 = at(M_ACCEL, n)
    FR0 = at(M_FORCE_RATE, n)
    FA0 = at(M_FORCE_ACCEL, n)
    for i in range(n):
        v_i = meas[at(M_VELOCITY, n) + i]
        f_i = fmeas[i]
        if k == 0:
            filters[f0 + i] = v_i
            filters[f0 + n + i] = f_i
        acc = filters[f0 + 2 * n + i] + beta * ((v_i - filters[f0 + i]) / ts - filters[f0 + 2 * n + i])
        dfo = filters[f0 + 3 * n + i]
        dfn = dfo + beta * ((f_i - filters[f0 + n + i]) / ts - dfo)
        ddf = filters[f0 + 4 * n + i] + beta * ((dfn - dfo) / ts - filters[f0 + 4 * n + i])
        filters[f0 + 2 * n + i] = acc
        filters[f0 + 3 * n + i] = dfn
        filters[f0 + 4 * n + i] = ddf
        filters[f0 + i] = v_i
        filters[f0 + n + i] = f_i
        meas[A0 + i] = acc
        meas[FR0 + i] = dfn
        meas[FA0 + i] = ddf
