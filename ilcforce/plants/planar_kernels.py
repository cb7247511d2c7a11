"""The five 2-DOF kernels (``ilcforce.plants.base``) of any 2-joint arm read from a model file, moving
in the plane normal to its parallel hinge axes (docs/model.md#model-file): compiled once for every
such arm, they read its packed vector at the address ``p`` and call the chain kernels of
``ilcforce.plants.chain`` with n = 2.

The packed vector: :data:`PLANE` floats describing the task plane, then the chain's own vector
(``chain.HEADER + 2 chain.LINK`` floats)::

    [ex (3), ey (3): the task's x and y axes in the world frame (unit, orthogonal, ex x ey = joint 1's axis),
     elbow (+1 up, -1 down), A1 (2): joint 1's axis in task coordinates, L1, L2: the link lengths in the
     plane, phi1_0: link 1's angle in the plane at q = 0, beta_0: link 2's angle from link 1 at q = 0,
     s2: +1 if joint 2's axis is joint 1's, -1 if opposite, the regressor's base columns (6: indices into
     the chain regressor's 20 columns, -1 unused; ``chain.base_columns``)]

Task coordinates are the world position's components along ex and ey; gravity is the chain's own
(the model's -z unless the experiment sets g), so it acts in the plane only through its in-plane part.
Joint 1 turns the arm counter-clockwise in (ex, ey), joint 2 by s2 times its angle; the working
mode is the sign of sin(beta) with beta = beta_0 + s2 q2, link 2's angle from link 1 in the plane
(elbow up: beta in (0, pi), the serial 2R arm's theta2 in (0, pi)).
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.plants import chain
from ilcforce.plants.base import PlantKernels, compile_kernels, params_view, task_from_dynamics
from ilcforce.plants.nd import compile_nd, from_dyn

__all__ = ["PLANE", "N_PACKED", "BASE_WIDTH", "kernels", "nd_kernel", "plane", "regressor", "jacobian_derivative"]

#: the regressor's width: at most this many base parameters (a planar 2R arm with gravity has 6)
BASE_WIDTH = 6
#: floats of the plane's description before the chain's vector
PLANE = 14 + BASE_WIDTH
#: the whole packed vector of a 2-joint arm
N_PACKED = PLANE + chain.HEADER + 2 * chain.LINK
_EX, _EY, _ELBOW, _A1, _L1, _L2, _PHI1, _BETA0, _S2, _BASE = 0, 3, 6, 7, 9, 10, 11, 12, 13, 14


@njit(cache=True, error_model="numpy")
def _ok(p, th2):
    return 1.0 if p[_ELBOW] * math.sin(p[_BETA0] + p[_S2] * th2) > 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def _project(p, v):
    """(ex . v, ey . v) for a world 3-vector v."""
    return (p[0] * v[0] + p[1] * v[1] + p[2] * v[2], p[3] * v[0] + p[4] * v[1] + p[5] * v[2])


@njit(cache=True, error_model="numpy")
def _point(p, q):
    """(Px, Py, J00, J01, J10, J11): the end effector in task coordinates and its planar Jacobian."""
    cp = p[PLANE:]
    J3 = chain.jacobian(cp, q)
    P = chain.forward_kinematics(cp, q)
    px, py = _project(p, P)
    J00, J10 = _project(p, J3[:, 0])
    J01, J11 = _project(p, J3[:, 1])
    return px, py, J00, J01, J10, J11


@njit(cache=True, error_model="numpy")
def _moving(p, th1, th2, d1, d2):
    """What the accel and dyn kernels share: the chain's parameters, q, dq, P, J, dJ and M (n = 2)."""
    cp = p[PLANE:]
    q = np.array([th1, th2])
    dq = np.array([d1, d2])
    px, py, J00, J01, J10, J11 = _point(p, q)
    dJ3 = chain.jacobian_derivative(cp, q, dq)
    dJ00, dJ10 = _project(p, dJ3[:, 0])
    dJ01, dJ11 = _project(p, dJ3[:, 1])
    return cp, q, dq, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, chain.joint_inertia(cp, q)


@njit(cache=True, error_model="numpy")
def _dynamics(p, th1, th2, d1, d2):
    """The DYN tuple of ilcforce.plants.base from the chain kernels (n = 2)."""
    cp, q, dq, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, M = _moving(p, th1, th2, d1, d2)
    C = chain.joint_coriolis(cp, q, dq)
    zero = np.zeros(2)
    G = chain.inverse_dynamics(cp, q, zero, zero, True)
    return (_ok(p, th2), px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
            M[0, 0], M[0, 1], M[1, 1], C[0, 0], C[0, 1], C[1, 0], C[1, 1], G[0], G[1])


def _kin_kernel(address, th1, th2):
    p = params_view(address, N_PACKED)
    px, py, J00, J01, J10, J11 = _point(p, np.array([th1, th2]))
    return (_ok(p, th2), px, py, J00, J01, J10, J11)


def _accel_kernel(address, th1, th2, d1, d2):
    p = params_view(address, N_PACKED)
    cp, q, dq, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, M = _moving(p, th1, th2, d1, d2)
    b = chain.inverse_dynamics(cp, q, dq, np.zeros(2), True)  # Cq dq + G_q by recursive Newton-Euler
    det = M[0, 0] * M[1, 1] - M[0, 1] * M[0, 1]
    return (_ok(p, th2), px, py, J00, J01, J10, J11, dJ00 * d1 + dJ01 * d2, dJ10 * d1 + dJ11 * d2, b[0], b[1],
            M[1, 1] / det, -M[0, 1] / det, M[0, 0] / det)


def _task_kernel(address, th1, th2, d1, d2):
    p = params_view(address, N_PACKED)
    return task_from_dynamics(_dynamics(p, th1, th2, d1, d2), d1, d2)  # eq. (4)


def _dyn_kernel(address, th1, th2, d1, d2):
    p = params_view(address, N_PACKED)
    return _dynamics(p, th1, th2, d1, d2)


def _ik_kernel(address, px, py):
    """The two-link planar closed form: beta = elbow acos(c), phi1 = atan2(dy, dx) - atan2(L2 sin beta,
    L1 + L2 c); then q1 = phi1 - phi1_0, q2 = s2 (beta - beta_0)."""
    p = params_view(address, N_PACKED)
    dx = px - p[_A1]
    dy = py - p[_A1 + 1]
    L1, L2 = p[_L1], p[_L2]
    c = (dx * dx + dy * dy - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    if not (-1.0 < c < 1.0):
        return (0.0, math.nan, math.nan)
    beta = p[_ELBOW] * math.acos(c)
    phi1 = math.atan2(dy, dx) - math.atan2(L2 * math.sin(beta), L1 + L2 * c)
    return (1.0, phi1 - p[_PHI1], p[_S2] * (beta - p[_BETA0]))


#: the DYN kernel as compiled code calls it (the n-joint kernel's source; the same function, options and cache)
_dyn_compiled = njit(cache=True, error_model="numpy")(_dyn_kernel)


def _nd_kernel(address, q, dq, level, out):
    """The n-joint interface's ``nd_dyn`` (ilcforce.plants.nd, n = 2) from the DYN kernel: the chain's
    numbers in the task plane, as the 2-joint loop sees them."""
    return from_dyn(_dyn_compiled(address, q[0], q[1], dq[0], dq[1]), dq[0], dq[1], level, out)


@functools.cache
def nd_kernel():
    """The ``nd_dyn`` of every 2-joint arm from a model file (compiled, or loaded from numba's cache, on
    first call)."""
    return compile_nd(_nd_kernel)


@functools.cache
def kernels() -> PlantKernels:
    """The interface kernels of every 2-joint arm from a model file (compiled, or loaded from numba's
    cache, on first call)."""
    return compile_kernels(_kin_kernel, _accel_kernel, _task_kernel, _dyn_kernel, _ik_kernel)


def plane(arm, elbow: float) -> np.ndarray:
    """The :data:`PLANE` floats of the 2-joint ``arm`` (a :class:`~ilcforce.plants.serial_arm.SerialArm`),
    or ValueError (one line) for an arm that is not two parallel hinges with the end effector on link 2.
    The task axes: ey along gravity's in-plane part, upwards (-g's); ex = ey x a (a: joint 1's axis),
    so that ex x ey = a. Without gravity in the plane, ex is the world x (else y) projected on it."""
    p = arm.packed
    n = arm.n
    where = arm.source or "the model"
    if n != 2:
        raise ValueError(f"{where}: the robot has {n} joints but the task has 2 dimensions; they must be equal")
    types = [p[chain.HEADER + chain.LINK * i] for i in range(2)]
    if any(t != chain.HINGE for t in types):
        raise ValueError(f"{where}: a planar 2-joint arm needs two revolute (hinge) joints; "
                         f"{', '.join(arm.joint_names)} include a slide joint")
    if int(p[1]) != 1:
        raise ValueError(f"{where}: end effector {arm.end_effector!r} is on the first link; it must move with the second")
    R, o, S = chain.frames(p, np.zeros(2))
    a1, a2 = np.array(S[0, :3]), np.array(S[1, :3])
    if np.linalg.norm(np.cross(a1, a2)) > 1e-9:
        raise ValueError(f"{where}: the joint axes {_vec(a1)} and {_vec(a2)} are not parallel; "
                         "a 2-joint arm must move in the plane normal to them")
    up = -np.asarray(arm.gravity_vector, dtype=np.float64)
    up = up - (up @ a1) * a1
    if np.linalg.norm(up) > 1e-12 * max(1.0, float(np.linalg.norm(arm.gravity_vector))):
        ey = up / np.linalg.norm(up)
        ex = np.cross(ey, a1)
    else:  # gravity normal to the plane, or none: the world x (or y) in the plane
        for world in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])):
            ex = world - (world @ a1) * a1
            if np.linalg.norm(ex) > 1e-6:
                break
        ex = ex / np.linalg.norm(ex)
        ey = np.cross(a1, ex)

    def in_plane(v):
        return np.array([ex @ v, ey @ v])
    # a point of each axis: z x (a x z) for S = [z; a x z]; its projection is the axis in the plane
    A1 = in_plane(np.cross(S[0, :3], S[0, 3:]))
    A2 = in_plane(np.cross(S[1, :3], S[1, 3:]))
    P = in_plane(chain.forward_kinematics(p, np.zeros(2)))
    L1, L2 = float(np.hypot(*(A2 - A1))), float(np.hypot(*(P - A2)))
    if min(L1, L2) < 1e-9:
        raise ValueError(f"{where}: a link has no length in the plane (L1 = {L1:.3g} m, L2 = {L2:.3g} m); "
                         "the arm cannot move its end effector in two dimensions")
    phi1 = math.atan2(A2[1] - A1[1], A2[0] - A1[0])
    beta0 = math.atan2(P[1] - A2[1], P[0] - A2[0]) - phi1
    s2 = 1.0 if a1 @ a2 > 0 else -1.0
    columns, _ = chain.base_columns(p)
    if len(columns) > BASE_WIDTH:
        raise ValueError(f"{where}: the arm's dynamics have {len(columns)} base parameters; a planar 2-joint arm has "
                         f"at most {BASE_WIDTH}")
    base = [*columns, *([-1] * (BASE_WIDTH - len(columns)))]
    return np.array([*ex, *ey, elbow, *A1, L1, L2, phi1, beta0, s2, *base], dtype=np.float64)


@njit(cache=True, error_model="numpy")
def _pick(Y, r, index):
    return Y[r, int(index)] if index >= 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2):
    """Y(q, dq, dq_r, ddq_r) as a (2, BASE_WIDTH) 12-tuple (row 0, then row 1) with Y a = Dq ddq_r +
    Cq(q, dq) dq_r + G_q, a the base parameters: the chain's regressor (Y pi = M ddq + C(q, dq) dq + G)
    at ddq_r, plus its velocity terms made bilinear by polarisation, C(q, dq) dq_r = (h(dq + dq_r) -
    h(dq) - h(dq_r)) / 2 with h(v) = C(q, v) v (the Christoffel form is symmetric in its two
    velocities), restricted to the base columns. ``p`` may be longer than the plant's vector."""
    cp = p[PLANE:]
    q = np.array([th1, th2])
    zero = np.zeros(2)
    Y = chain.regressor(cp, q, zero, np.array([rr1, rr2]))
    Y = Y + 0.5 * (chain.regressor(cp, q, np.array([d1 + r1, d2 + r2]), zero)
                   - chain.regressor(cp, q, np.array([d1, d2]), zero)
                   - chain.regressor(cp, q, np.array([r1, r2]), zero)
                   + chain.regressor(cp, q, zero, zero))
    b = p[_BASE:_BASE + BASE_WIDTH]
    return (_pick(Y, 0, b[0]), _pick(Y, 0, b[1]), _pick(Y, 0, b[2]), _pick(Y, 0, b[3]), _pick(Y, 0, b[4]),
            _pick(Y, 0, b[5]),
            _pick(Y, 1, b[0]), _pick(Y, 1, b[1]), _pick(Y, 1, b[2]), _pick(Y, 1, b[3]), _pick(Y, 1, b[4]),
            _pick(Y, 1, b[5]))


@njit(cache=True, error_model="numpy")
def jacobian_derivative(p, th1, th2, d1, d2):
    """(dJ00, dJ01, dJ10, dJ11) in task coordinates; ``p`` may be longer than the plant's vector."""
    dJ3 = chain.jacobian_derivative(p[PLANE:], np.array([th1, th2]), np.array([d1, d2]))
    dJ00, dJ10 = _project(p, dJ3[:, 0])
    dJ01, dJ11 = _project(p, dJ3[:, 1])
    return dJ00, dJ01, dJ10, dJ11


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3g}" for x in v) + ")"
