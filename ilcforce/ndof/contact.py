"""The true plant pressed against the wall, in n dimensions (docs/model.md#n-dof, docs/model.md#wall): what the loop
(``ilcforce.loop``) integrates. The plant's kernel output (``nd_dyn``, ``ilcforce.plants.nd``) turned into the wall's
task frame, the contact force of ``ilcforce.task.wall_force`` (its normal force, with the wall's damper) and the
wall's friction in its plane (``ilcforce.task.friction_scale``) and the disturbance as joint forces, and the joint
accelerations under a torque (eq. 1), on scratch arrays it is given (no allocation).
"""

from __future__ import annotations

import math

from ilcforce.compiled.dense import cholesky, cholesky_solve
from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import at
from ilcforce.ndof.algebra import OUT_B, OUT_DJ, OUT_DJV, OUT_M
from ilcforce.task import (
    AFTER_FRAME_DAMPING, AFTER_FRAME_FRICTION, AFTER_FRAME_FRICTION_VELOCITY, friction_scale, wall_force,
)

__all__ = ["to_task", "drift", "stage"]


@njit(cache=True, error_model="numpy", inline="always")
def to_task(n, R, out, X, JX, dJv, DJ, level):
    """Rotate the kernel's world quantities into the task frame: X = R P, J_X = R J (and R dJ dq, R dJ)."""
    for i in range(n):
        s = 0.0
        for k in range(n):
            s += R[3 + i * n + k] * out[k]
        X[i] = s
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += R[3 + i * n + k] * out[n + k * n + j]
            JX[i * n + j] = s
    if level >= 1:
        d0 = at(OUT_DJV, n)
        for i in range(n):
            s = 0.0
            for k in range(n):
                s += R[3 + i * n + k] * out[d0 + k]
            dJv[i] = s
    if level >= 2:
        d0 = at(OUT_DJ, n)
        for i in range(n):
            for j in range(n):
                s = 0.0
                for k in range(n):
                    s += R[3 + i * n + k] * out[d0 + k * n + j]
                DJ[i * n + j] = s


@njit(cache=True, error_model="numpy", inline="always")
def drift(dyn, p, q, dq, wall, fa, fv, out, X, JX, dJv, r, L, fc, at_sample):
    """The true plant pressed against the wall, torque left out (eq. 1): M ddq = tau + r, r = J_X^T f - b,
    f the force on the robot in the task frame (the disturbance and the wall's reaction: -w F_n along the normal
    axis fa, friction in the plane). Fills X, J_X, r, the Cholesky factor L of M and, ``at_sample`` (the loop
    reads them there; an RK4 stage does not), dJ_X dq and the contact force F in the task frame into fc (the
    force the end-effector applies in the convention of ``ilcforce.task``, F = -w f: F_n at fa, w mu F_n u in
    the plane, u the smoothed unit of the in-plane velocity; at a stage fc is the friction's scratch).
    Returns (ok, F_n)."""
    n = q.shape[0]
    ok = dyn(p, q, dq, 1, out)
    if ok == 0.0:
        return False, 0.0
    to_task(n, wall, out, X, JX, dJv, JX, 1 if at_sample else 0)
    ye, ke, w = wall[0], wall[1], wall[2]
    after = 3 + n * n  # the damper and friction after R (ilcforce.task.WALL_*)
    de = wall[after + AFTER_FRAME_DAMPING]
    mu = wall[after + AFTER_FRAME_FRICTION]
    vn = 0.0
    if de != 0.0:  # the normal velocity, for the damper
        for j in range(n):
            vn += JX[fa * n + j] * dq[j]
    f_wall = wall_force(X[fa], vn, ye, ke, de, w)
    if at_sample:  # the contact force is read at the sample only (an RK4 stage uses fc as the friction's scratch)
        for i in range(n):
            fc[i] = 0.0
        fc[fa] = f_wall
    b0 = at(OUT_B, n)
    for j in range(n):
        s = 0.0
        for i in range(n):  # the disturbance on the robot (eq. 1, tau_v = J^T F_v) ...
            s -= JX[i * n + j] * fv[i]
        r[j] = s - JX[fa * n + j] * w * f_wall - out[b0 + j]  # ... and the wall's reaction
    if mu != 0.0 and f_wall > 0.0:  # Coulomb friction in the wall's plane, opposing the in-plane velocity
        speed2 = 0.0
        for i in range(n):
            if i != fa:
                v = 0.0
                for j in range(n):
                    v += JX[i * n + j] * dq[j]
                fc[i] = v  # the in-plane velocity, for now
                speed2 += v * v
        scale = friction_scale(math.sqrt(speed2), wall[after + AFTER_FRAME_FRICTION_VELOCITY])
        for i in range(n):
            if i != fa:
                f_i = -mu * f_wall * scale * fc[i]  # on the robot
                fc[i] = -w * f_i
                for j in range(n):
                    r[j] += JX[i * n + j] * f_i
    if not cholesky(n, out, at(OUT_M, n), L):
        return False, f_wall
    return True, f_wall


@njit(cache=True, error_model="numpy", inline="always")
def stage(dyn, p, q, dq, tau, wall, fa, fv, out, X, JX, dJv, r, L, fc, acc):
    """Joint accelerations of the true plant under torque tau into acc (fc: scratch for the contact force).
    Returns ok."""
    n = q.shape[0]
    ok, _f = drift(dyn, p, q, dq, wall, fa, fv, out, X, JX, dJv, r, L, fc, False)
    if not ok:
        return False
    for j in range(n):
        acc[j] = tau[j] + r[j]
    cholesky_solve(n, L, acc, acc)
    return True
