"""Rigid-body algorithms of a serial chain of revolute and prismatic joints on one packed vector
(docs/model.md#model-file): forward kinematics, the point Jacobian and its derivative, recursive
Newton-Euler inverse dynamics, the composite-rigid-body inertia, the Christoffel Coriolis matrix and
the joint-torque regressor.

Every quantity is in the world frame, with spatial (Plücker) vectors taken at the world origin
(Featherstone, Rigid Body Dynamics Algorithms, 2008, ch. 2): a motion vector is [w; v_O] (angular
velocity; velocity of the body-fixed point at the origin), a force vector [n_O; f]. In these
coordinates a joint's axis S_i is constant in the frame of either body it joins, and its rate is
dS_i/dt = v_i x S_i, so the recursions need no frame change between links.

The packed vector ``p`` (built by ``ilcforce.plants.model_file``): a header of :data:`HEADER` floats

    [n, end-effector link, end-effector offset (3, in that link's frame), gravity (3, world)]

then, per link i = 0..n-1, :data:`LINK` floats

    [joint type (HINGE or SLIDE), q0, placement: position (3) and rotation (9, row-major) of the link
     frame at q = q0 in link i-1's frame (world's for i = 0), joint anchor (3) and unit axis (3) in
     the link frame, mass, centre of mass (3, link frame), inertia about it (9, link frame)]

A hinge turns the link about its axis through the anchor by q - q0, a slide moves it along its axis
by q - q0 (MuJoCo's convention for hinge and slide joints, so q is the model file's joint value).
Nothing here calls the library that read the file.
"""

from __future__ import annotations

import math

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs (ilcforce/compiled/jit.py)

__all__ = ["HEADER", "LINK", "HINGE", "SLIDE", "N_INERTIAL", "link_count", "frames", "forward_kinematics",
           "jacobian", "jacobian_derivative", "inverse_dynamics", "joint_inertia", "joint_coriolis",
           "regressor", "slotine_li_regressor", "inertial_parameters", "base_columns", "base_parameters",
           "inertial_parameter_name", "INERTIAL_NAMES", "potential_energy"]

HEADER = 8
LINK = 33
HINGE = 0.0
SLIDE = 1.0
#: inertial parameters per link: [m, m cx, m cy, m cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz] (I about the link frame's origin)
N_INERTIAL = 10
#: their names, in that order
INERTIAL_NAMES = ("m", "mcx", "mcy", "mcz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
# offsets inside a link's block
_TYPE, _Q0, _POS, _ROT, _ANCHOR, _AXIS, _MASS, _COM, _INERTIA = 0, 1, 2, 5, 14, 17, 20, 21, 24


def link_count(p) -> int:
    return int(p[0])


# --- small fixed-size algebra (loops, no BLAS) ------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _cross(a, b):
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


@njit(cache=True, error_model="numpy")
def _mv(A, x):
    """A x for a (r, c) matrix."""
    r, c = A.shape
    out = np.zeros(r)
    for i in range(r):
        s = 0.0
        for k in range(c):
            s += A[i, k] * x[k]
        out[i] = s
    return out


@njit(cache=True, error_model="numpy")
def _mtv(A, x):
    """A^T x for a (r, c) matrix."""
    r, c = A.shape
    out = np.zeros(c)
    for k in range(r):
        for i in range(c):
            out[i] += A[k, i] * x[k]
    return out


@njit(cache=True, error_model="numpy")
def _mm(A, B):
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            for j in range(B.shape[1]):
                out[i, j] += a * B[k, j]
    return out


@njit(cache=True, error_model="numpy")
def _block3(p, k):
    """The 3 x 3 matrix stored row-major at p[k:k + 9]."""
    out = np.empty((3, 3))
    for r in range(3):
        for c in range(3):
            out[r, c] = p[k + 3 * r + c]
    return out


@njit(cache=True, error_model="numpy")
def _axis_rotation(axis, angle):
    """Rotation by ``angle`` about the unit ``axis`` (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    x, y, z = axis[0], axis[1], axis[2]
    return np.array([[c + t * x * x, t * x * y - s * z, t * x * z + s * y],
                     [t * x * y + s * z, c + t * y * y, t * y * z - s * x],
                     [t * x * z - s * y, t * y * z + s * x, c + t * z * z]])


@njit(cache=True, error_model="numpy")
def _crm(v, m):
    """v x m for motion vectors (the spatial cross product [w x mw; w x mv + u x mw])."""
    w, u = v[:3], v[3:]
    out = np.empty(6)
    out[:3] = _cross(w, m[:3])
    out[3:] = _cross(w, m[3:]) + _cross(u, m[:3])
    return out


@njit(cache=True, error_model="numpy")
def _crf(v, f):
    """v x* f for a motion vector v and a force vector f ([w x n + u x f; w x f])."""
    w, u = v[:3], v[3:]
    out = np.empty(6)
    out[:3] = _cross(w, f[:3]) + _cross(u, f[3:])
    out[3:] = _cross(w, f[3:])
    return out


@njit(cache=True, error_model="numpy")
def _dot(a, b):
    s = 0.0
    for k in range(a.shape[0]):
        s += a[k] * b[k]
    return s


# --- kinematics ------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def frames(p, q):
    """(R, o, S): each link frame's world rotation (n, 3, 3) and origin (n, 3), and each joint's
    axis as a world motion vector at the origin (n, 6): [z; a x z] for a hinge through a, [0; z] for a slide."""
    n = int(p[0])
    R = np.empty((n, 3, 3))
    o = np.empty((n, 3))
    S = np.zeros((n, 6))
    Rp = np.eye(3)
    op = np.zeros(3)
    for i in range(n):
        b = HEADER + LINK * i
        Rf = _mm(Rp, _block3(p, b + _ROT))  # the link frame at q = q0
        of = op + _mv(Rp, p[b + _POS:b + _POS + 3])
        axis = p[b + _AXIS:b + _AXIS + 3]
        z = _mv(Rf, axis)
        t = q[i] - p[b + _Q0]
        if p[b + _TYPE] == HINGE:
            anchor = p[b + _ANCHOR:b + _ANCHOR + 3]
            a = of + _mv(Rf, anchor)
            Ri = _mm(Rf, _axis_rotation(axis, t))
            oi = a - _mv(Ri, anchor)
            S[i, :3] = z
            S[i, 3:] = _cross(a, z)
        else:
            Ri = Rf
            oi = of + z * t
            S[i, 3:] = z
        R[i] = Ri
        o[i] = oi
        Rp = Ri
        op = oi
    return R, o, S


@njit(cache=True, error_model="numpy")
def _end_effector(p, R, o):
    """(link index, world position) of the end effector."""
    e = int(p[1])
    return e, o[e] + _mv(R[e], p[2:5])


@njit(cache=True, error_model="numpy")
def forward_kinematics(p, q):
    """The end effector's world position (3,)."""
    R, o, S = frames(p, q)
    return _end_effector(p, R, o)[1]


@njit(cache=True, error_model="numpy")
def jacobian(p, q):
    """The end effector's linear-velocity Jacobian (3, n): column j is w_j x P + v_j for S_j = [w_j; v_j]
    (zero for a joint after the end effector's link)."""
    R, o, S = frames(p, q)
    e, pe = _end_effector(p, R, o)
    n = S.shape[0]
    J = np.zeros((3, n))
    for j in range(e + 1):
        J[:, j] = _cross(S[j, :3], pe) + S[j, 3:]
    return J


@njit(cache=True, error_model="numpy")
def jacobian_derivative(p, q, dq):
    """dJ/dt (3, n) along dq: column j is dw_j x P + w_j x dP + dv_j with dS_j = v_j x S_j and v_j the
    velocity of link j."""
    R, o, S = frames(p, q)
    e, pe = _end_effector(p, R, o)
    n = S.shape[0]
    J = np.zeros((3, n))
    dJ = np.zeros((3, n))
    v = np.zeros(6)
    for j in range(e + 1):
        J[:, j] = _cross(S[j, :3], pe) + S[j, 3:]
    dpe = _mv(J, dq)
    for j in range(e + 1):
        v = v + S[j] * dq[j]
        dS = _crm(v, S[j])
        dJ[:, j] = _cross(dS[:3], pe) + _cross(S[j, :3], dpe) + dS[3:]
    return dJ


# --- inertia ---------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _spatial_inertia(p, i, R, o):
    """Link i's spatial inertia (6, 6) at the world origin, in world axes:
    [[Ic + m (|c|^2 1 - c c^T), m [c]x], [m [c]x^T, m 1]] with c its world centre of mass."""
    b = HEADER + LINK * i
    m = p[b + _MASS]
    Ri = R[i]
    c = o[i] + _mv(Ri, p[b + _COM:b + _COM + 3])
    Ic = _mm(_mm(Ri, _block3(p, b + _INERTIA)), Ri.T.copy())
    out = np.zeros((6, 6))
    cc = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
    for r in range(3):
        for k in range(3):
            out[r, k] = Ic[r, k] - m * c[r] * c[k]
        out[r, r] += m * cc
        out[3 + r, 3 + r] = m
    cx = np.array([[0.0, -c[2], c[1]], [c[2], 0.0, -c[0]], [-c[1], c[0], 0.0]])
    for r in range(3):
        for k in range(3):
            out[r, 3 + k] = m * cx[r, k]
            out[3 + k, r] = m * cx[r, k]
    return out


@njit(cache=True, error_model="numpy")
def _composite_inertias(p, R, o):
    """Ic (n, 6, 6): Ic_j = sum of the spatial inertias of links j..n-1."""
    n = R.shape[0]
    Ic = np.zeros((n, 6, 6))
    acc = np.zeros((6, 6))
    for j in range(n - 1, -1, -1):
        acc = acc + _spatial_inertia(p, j, R, o)
        Ic[j] = acc
    return Ic


@njit(cache=True, error_model="numpy")
def joint_inertia(p, q):
    """M(q) (n, n) by the composite-rigid-body algorithm: M_ij = S_i . (Ic_j S_j) for i <= j."""
    R, o, S = frames(p, q)
    n = S.shape[0]
    Ic = _composite_inertias(p, R, o)
    M = np.zeros((n, n))
    for j in range(n):
        F = _mv(Ic[j], S[j])
        for i in range(j + 1):
            M[i, j] = _dot(S[i], F)
            M[j, i] = M[i, j]
    return M


@njit(cache=True, error_model="numpy")
def inertia_gradient(p, q):
    """dM/dq_k (n, n, n), [k, i, j]: for i <= j, 0 when k <= i; -(S_k x S_i) . (Ic_j S_j) when
    i < k <= j; -(S_k x S_i) . (Ic_k S_j) - (S_k x S_j) . (Ic_k S_i) when k > j (a quantity fixed to the
    links after joint k turns with S_k: dX/dq_k = S_k x X, dI/dq_k = S_k x* I - I S_k x)."""
    R, o, S = frames(p, q)
    n = S.shape[0]
    Ic = _composite_inertias(p, R, o)
    dM = np.zeros((n, n, n))
    for k in range(n):
        for i in range(n):
            ski = _crm(S[k], S[i])
            for j in range(i, n):
                if k <= i:
                    value = 0.0
                elif k <= j:
                    value = -_dot(ski, _mv(Ic[j], S[j]))
                else:
                    value = -_dot(ski, _mv(Ic[k], S[j])) - _dot(_crm(S[k], S[j]), _mv(Ic[k], S[i]))
                dM[k, i, j] = value
                dM[k, j, i] = value
    return dM


@njit(cache=True, error_model="numpy")
def joint_coriolis(p, q, dq):
    """The Christoffel Coriolis matrix C(q, dq) (n, n): C_ij = sum_k G_ijk dq_k with
    G_ijk = (dM_ij/dq_k + dM_ik/dq_j - dM_jk/dq_i) / 2, so dM/dt - 2C is skew-symmetric."""
    dM = inertia_gradient(p, q)
    n = dM.shape[0]
    C = np.zeros((n, n))
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += 0.5 * (dM[k, i, j] + dM[j, i, k] - dM[i, j, k]) * dq[k]
            C[i, j] = s
    return C


# --- dynamics --------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def _velocities_accelerations(p, S, dq, ddq, gravity):
    """Each link's spatial velocity and acceleration (n, 6), the base accelerating at -g when
    ``gravity`` (gravity as a fictitious upward acceleration of the base)."""
    n = S.shape[0]
    v = np.zeros((n, 6))
    a = np.zeros((n, 6))
    vp = np.zeros(6)
    ap = np.zeros(6)
    if gravity:
        ap[3:] = -p[5:8]
    for i in range(n):
        vi = vp + S[i] * dq[i]
        ai = ap + S[i] * ddq[i] + _crm(vi, S[i]) * dq[i]
        v[i] = vi
        a[i] = ai
        vp = vi
        ap = ai
    return v, a


@njit(cache=True, error_model="numpy")
def inverse_dynamics(p, q, dq, ddq, gravity):
    """tau = M ddq + C dq (+ g(q) when ``gravity``) by recursive Newton-Euler: f_i = I_i a_i + v_i x* I_i v_i,
    tau_i = S_i . sum_{l >= i} f_l."""
    R, o, S = frames(p, q)
    n = S.shape[0]
    v, a = _velocities_accelerations(p, S, dq, ddq, gravity)
    tau = np.zeros(n)
    F = np.zeros(6)
    for i in range(n - 1, -1, -1):
        I6 = _spatial_inertia(p, i, R, o)
        F = F + _mv(I6, a[i]) + _crf(v[i], _mv(I6, v[i]))
        tau[i] = _dot(S[i], F)
    return tau


@njit(cache=True, error_model="numpy")
def _to_link(Ri, oi, m):
    """A world motion vector at the origin in link coordinates (at the link origin, in its axes)."""
    out = np.empty(6)
    out[:3] = _mtv(Ri, m[:3])
    out[3:] = _mtv(Ri, m[3:] + _cross(m[:3], oi))
    return out


@njit(cache=True, error_model="numpy")
def _link_regressor(v, vr, a):
    """A (6, 10) with I(pi) a + v x* I(pi) vr = A pi for a link's inertial parameters pi (N_INERTIAL),
    v = [w; u], vr = [wr; ur] and a = [al; al_lin] in link coordinates (I x = [Ibar xw + h x xu; m xu + xw x h]):
    force [Ibar al + h x al_lin + w x (Ibar wr + h x ur) + u x (m ur + wr x h); m (al_lin + w x ur) + al x h
    + w x (wr x h)], h = m c. With vr = v it is the link's Newton-Euler force I a + v x* I v."""
    w, u = v[:3], v[3:]
    wr, ur = vr[:3], vr[3:]
    al, alin = a[:3], a[3:]
    A = np.zeros((6, 10))
    A[:3, 0] = _cross(u, ur)
    A[3:, 0] = alin + _cross(w, ur)
    e = np.zeros(3)
    for k in range(3):  # the columns of h = m c
        e[:] = 0.0
        e[k] = 1.0
        A[:3, 1 + k] = _cross(e, alin) + _cross(w, _cross(e, ur)) + _cross(u, _cross(wr, e))
        A[3:, 1 + k] = _cross(al, e) + _cross(w, _cross(wr, e))
    # Ibar x for x = [x0, x1, x2]: rows [xx x0 + xy x1 + xz x2, xy x0 + yy x1 + yz x2, xz x0 + yz x1 + zz x2]
    L_al = np.array([[al[0], al[1], al[2], 0.0, 0.0, 0.0],
                     [0.0, al[0], 0.0, al[1], al[2], 0.0],
                     [0.0, 0.0, al[0], 0.0, al[1], al[2]]])
    L_wr = np.array([[wr[0], wr[1], wr[2], 0.0, 0.0, 0.0],
                     [0.0, wr[0], 0.0, wr[1], wr[2], 0.0],
                     [0.0, 0.0, wr[0], 0.0, wr[1], wr[2]]])
    for c in range(6):
        A[:3, 4 + c] = L_al[:, c] + _cross(w, L_wr[:, c])
    return A


@njit(cache=True, error_model="numpy")
def _reference_motion(p, S, dq, dq_r, ddq_r):
    """Each link's velocity v_i, reference velocity vr_i = sum_{l <= i} S_l dq_r,l and reference acceleration
    ar_i = ar_{i-1} + S_i ddq_r,i + (v_i x S_i) dq_r,i (n, 6), the base accelerating at -g: the motion of
    Slotine & Li's reference trajectory seen from the robot moving at dq (Niemeyer & Slotine 1991)."""
    n = S.shape[0]
    v = np.zeros((n, 6))
    vr = np.zeros((n, 6))
    ar = np.zeros((n, 6))
    vp = np.zeros(6)
    vrp = np.zeros(6)
    ap = np.zeros(6)
    ap[3:] = -p[5:8]
    for i in range(n):
        vp = vp + S[i] * dq[i]
        vrp = vrp + S[i] * dq_r[i]
        ap = ap + S[i] * ddq_r[i] + _crm(vp, S[i]) * dq_r[i]
        v[i] = vp
        vr[i] = vrp
        ar[i] = ap
    return v, vr, ar


@njit(cache=True, error_model="numpy")
def _newton_euler_regressor(p, R, o, S, dq, dq_r, ddq_r):
    """Y_NE (n, 10 n) with Y_NE pi = M ddq_r + C_NE(q, dq) dq_r + g by Newton-Euler on the reference motion
    (:func:`_reference_motion`): link l's force f_l = I_l ar_l + v_l x* I_l vr_l, tau_j = sum_{l >= j} S_j . f_l,
    in link l's coordinates. Its velocity part is bilinear in (dq, dq_r) and equals C(q, dq) dq when dq_r = dq."""
    n = S.shape[0]
    v, vr, ar = _reference_motion(p, S, dq, dq_r, ddq_r)
    Y = np.zeros((n, N_INERTIAL * n))
    for l in range(n):
        A = _link_regressor(_to_link(R[l], o[l], v[l]), _to_link(R[l], o[l], vr[l]), _to_link(R[l], o[l], ar[l]))
        for j in range(l + 1):
            Y[j, N_INERTIAL * l:N_INERTIAL * (l + 1)] = _mtv(A, _to_link(R[l], o[l], S[j]))
    return Y


@njit(cache=True, error_model="numpy")
def slotine_li_regressor(p, q, dq, dq_r, ddq_r):
    """Y (n, 10 n) with Y pi = M(q) ddq_r + C(q, dq) dq_r + g(q), C the Christoffel Coriolis matrix
    (:func:`joint_coriolis`, so dM/dt - 2 C is skew-symmetric, as Slotine & Li's proof asks), for pi the links'
    inertial parameters (:func:`inertial_parameters`). Newton-Euler's velocity part is bilinear in (dq, dq_r);
    its symmetric half, (Y_NE(dq, dq_r) + Y_NE(dq_r, dq)) / 2, is the Christoffel form (the symmetric bilinear
    form whose quadratic form is C(q, v) v). Being a function of M and g only, its columns keep the dependencies
    of :func:`base_columns`. With dq_r = dq, ddq_r = ddq it is :func:`regressor`."""
    R, o, S = frames(p, q)
    return 0.5 * (_newton_euler_regressor(p, R, o, S, dq, dq_r, ddq_r) + _newton_euler_regressor(p, R, o, S, dq_r, dq, ddq_r))


@njit(cache=True, error_model="numpy")
def regressor(p, q, dq, ddq):
    """Y (n, 10 n) with Y pi = inverse_dynamics(p, q, dq, ddq, True) for pi the links' inertial
    parameters (:func:`inertial_parameters`): :func:`slotine_li_regressor` along the motion itself."""
    return slotine_li_regressor(p, q, dq, dq, ddq)


def inertial_parameters(p) -> np.ndarray:
    """(n, 10): per link [m, m c (3), I about the link frame's origin (xx, xy, xz, yy, yz, zz)], link frame."""
    n = link_count(p)
    out = np.empty((n, N_INERTIAL))
    for i in range(n):
        b = HEADER + LINK * i
        m = p[b + _MASS]
        c = np.asarray(p[b + _COM:b + _COM + 3])
        Ib = np.asarray(p[b + _INERTIA:b + _INERTIA + 9]).reshape(3, 3) + m * (c @ c * np.eye(3) - np.outer(c, c))
        out[i] = [m, *(m * c), Ib[0, 0], Ib[0, 1], Ib[0, 2], Ib[1, 1], Ib[1, 2], Ib[2, 2]]
    return out


def base_columns(chain_packed, states: int = 40, seed: int = 0):
    """(B, beta): the chain regressor's columns B whose parameters are identifiable (the base
    parameters a = pi_B + beta pi_D, pi_D the other columns' inertial parameters), chosen in column
    order by their residual against the columns chosen before, on random states (a fixed seed: the
    same columns for the nominal and the true plant, whose geometry is the same)."""
    rng = np.random.default_rng(seed)
    n = link_count(chain_packed)
    rows = [regressor(chain_packed, rng.uniform(-np.pi, np.pi, n), rng.uniform(-2, 2, n), rng.uniform(-5, 5, n))
            for _ in range(states)]
    W = np.vstack(rows)
    scale = np.linalg.norm(W, axis=0)
    chosen: list[int] = []
    for c in range(W.shape[1]):
        if scale[c] <= 1e-12 * scale.max():
            continue
        trial = W[:, [*chosen, c]]
        if np.linalg.matrix_rank(trial / np.linalg.norm(trial, axis=0), tol=1e-9) == len(chosen) + 1:
            chosen.append(c)
    others = [c for c in range(W.shape[1]) if c not in chosen]
    beta = np.linalg.lstsq(W[:, chosen], W[:, others], rcond=None)[0] if others else np.zeros((len(chosen), 0))
    return chosen, beta


def base_parameters(p, columns, beta) -> np.ndarray:
    """a = pi_B + beta pi_D (:func:`base_columns`), shape (len(columns),): the base parameters of the chain ``p``."""
    pi = inertial_parameters(p).ravel()
    others = [c for c in range(pi.size) if c not in columns]
    return pi[columns] + (beta @ pi[others] if others else 0.0)


def inertial_parameter_name(links, column: int) -> str:
    """The name of the regressor's column ``column`` (``link2.mcx``), ``links`` the links' names."""
    return f"{links[column // N_INERTIAL]}.{INERTIAL_NAMES[column % N_INERTIAL]}"


@njit(cache=True, error_model="numpy")
def potential_energy(p, q):
    """V = -sum_i m_i g . c_i (J), so that g(q) = dV/dq."""
    R, o, S = frames(p, q)
    V = 0.0
    for i in range(S.shape[0]):
        b = HEADER + LINK * i
        c = o[i] + _mv(R[i], p[b + _COM:b + _COM + 3])
        V -= p[b + _MASS] * _dot(p[5:8], c)
    return V
