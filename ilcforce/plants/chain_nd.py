"""The n-joint kernel (``ilcforce.plants.nd``) of a serial chain: the algorithms of ``ilcforce.plants.chain``
written to allocate nothing, for the n-joint loop's four calls per RK4 step.

``chain.py`` stays the readable reference (numpy arrays per call, one function per quantity); this
kernel computes the same quantities in one pass over the links with every intermediate in local
tuples or in the scratch space of ``out`` after the interface's entries, and only what the level asks
for: level 0 the frames, P and J; level 1 also the links' velocities, dJ/dt dq, the spatial inertias,
M by composite rigid bodies and b = C dq + g by recursive Newton-Euler at ddq = 0 (the Coriolis
matrix is not formed); level 2 also dJ/dt, g = S_i . (Ic_i a_0) and the Christoffel C from dM/dq.
tests/test_plant_nd.py holds it to ``chain.py`` and to MuJoCo to 1e-12 relative, and measures that it
allocates nothing. Measured on the 3-joint arm (``python -m benchmarks.nd_kernels``, 2 shared cores,
rough): 135 / 315 / 600 ns a call at levels 0 / 1 / 2, where a control step on chain.py's functions
costs 41 us.

The layout is ``nd.offsets(n, 3)``: the end effector's position has three coordinates whatever n
is, so the kernel is the n-joint interface's ``nd_dyn`` for n = 3 (``SerialArm.nd_kernel``); for
other n it is the same kernel with three rows in P, J and dJ (the tests run it on 2- and 4-joint chains).
The scratch: :data:`LINK_SCRATCH` floats per link (frame, axis, rates, inertias), then n^3 (dM/dq)
at level 2. Notation as in ``chain.py`` (spatial vectors at the world origin, world axes).
"""

from __future__ import annotations

import functools
import math

from ilcforce.compiled.jit import njit
from ilcforce.plants.base import params_view
from ilcforce.plants.chain import (
    _ANCHOR, _AXIS, _COM, _INERTIA, _MASS, _POS, _Q0, _ROT, _TYPE, HEADER, HINGE, LINK, N_INERTIAL,
)
from ilcforce.plants.nd import layout, nd_layout

__all__ = ["TASK", "LINK_SCRATCH", "scratch", "width", "kernel", "jacobian_rate_times", "slotine_li_regressor"]

#: the task: the end effector's world position
TASK = 3
#: scratch floats per link: R (9), o (3), S (6), dS = v x S (6), f (6), I (10), Ic (10), Ic S (6)
LINK_SCRATCH = 56
_R, _O, _S, _DS, _F, _I, _IC, _ICS = 0, 9, 12, 18, 24, 30, 40, 50


def scratch(n: int) -> int:
    """The scratch floats the kernel uses after the interface's entries, for an n-joint chain."""
    return LINK_SCRATCH * n + n * n * n


def width(n: int) -> int:
    """The length of ``out`` for an n-joint chain."""
    return layout(n, TASK)[-1] + scratch(n)


# --- fixed-size algebra on tuples --------------------------------------------------------------------
# a 3 x 3 matrix is a row-major 9-tuple, a spatial vector a 6-tuple [w; u], a spatial inertia at the
# origin the 10-tuple (m, h = m c (3), Ibar (xx, xy, xz, yy, yz, zz)): [[Ibar, [h]x], [[h]x^T, m 1]]

@njit(cache=True, error_model="numpy")
def _cross(a0, a1, a2, b0, b1, b2):
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@njit(cache=True, error_model="numpy")
def _mm(A, B):
    return (A[0] * B[0] + A[1] * B[3] + A[2] * B[6], A[0] * B[1] + A[1] * B[4] + A[2] * B[7],
            A[0] * B[2] + A[1] * B[5] + A[2] * B[8],
            A[3] * B[0] + A[4] * B[3] + A[5] * B[6], A[3] * B[1] + A[4] * B[4] + A[5] * B[7],
            A[3] * B[2] + A[4] * B[5] + A[5] * B[8],
            A[6] * B[0] + A[7] * B[3] + A[8] * B[6], A[6] * B[1] + A[7] * B[4] + A[8] * B[7],
            A[6] * B[2] + A[7] * B[5] + A[8] * B[8])


@njit(cache=True, error_model="numpy")
def _mv(A, x0, x1, x2):
    return (A[0] * x0 + A[1] * x1 + A[2] * x2, A[3] * x0 + A[4] * x1 + A[5] * x2, A[6] * x0 + A[7] * x1 + A[8] * x2)


@njit(cache=True, error_model="numpy")
def _get3(a, k):
    return a[k], a[k + 1], a[k + 2]


@njit(cache=True, error_model="numpy")
def _get6(a, k):
    return a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5]


@njit(cache=True, error_model="numpy")
def _get9(a, k):
    return a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5], a[k + 6], a[k + 7], a[k + 8]


@njit(cache=True, error_model="numpy")
def _get10(a, k):
    return a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5], a[k + 6], a[k + 7], a[k + 8], a[k + 9]


@njit(cache=True, error_model="numpy")
def _put3(a, k, x):
    a[k], a[k + 1], a[k + 2] = x[0], x[1], x[2]


@njit(cache=True, error_model="numpy")
def _put6(a, k, x):
    a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5] = x[0], x[1], x[2], x[3], x[4], x[5]


@njit(cache=True, error_model="numpy")
def _put9(a, k, x):
    a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5], a[k + 6], a[k + 7], a[k + 8] = x


@njit(cache=True, error_model="numpy")
def _put10(a, k, x):
    a[k], a[k + 1], a[k + 2], a[k + 3], a[k + 4], a[k + 5], a[k + 6], a[k + 7], a[k + 8], a[k + 9] = x


@njit(cache=True, error_model="numpy")
def _dot6(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]


@njit(cache=True, error_model="numpy")
def _crm(v, s):
    """v x s for motion vectors: [w x sw; w x su + u x sw]."""
    a0, a1, a2 = _cross(v[0], v[1], v[2], s[0], s[1], s[2])
    b0, b1, b2 = _cross(v[0], v[1], v[2], s[3], s[4], s[5])
    c0, c1, c2 = _cross(v[3], v[4], v[5], s[0], s[1], s[2])
    return a0, a1, a2, b0 + c0, b1 + c1, b2 + c2


@njit(cache=True, error_model="numpy")
def _crf(v, f):
    """v x* f for a motion vector v and a force vector f: [w x n + u x fl; w x fl]."""
    a0, a1, a2 = _cross(v[0], v[1], v[2], f[0], f[1], f[2])
    b0, b1, b2 = _cross(v[3], v[4], v[5], f[3], f[4], f[5])
    c0, c1, c2 = _cross(v[0], v[1], v[2], f[3], f[4], f[5])
    return a0 + b0, a1 + b1, a2 + b2, c0, c1, c2


@njit(cache=True, error_model="numpy")
def _inertia_times(I, x):
    """I x for a spatial inertia I and a motion vector x = [w; u]: [Ibar w + h x u; m u - h x w]."""
    m, h0, h1, h2, xx, xy, xz, yy, yz, zz = I
    w0, w1, w2, u0, u1, u2 = x
    a0, a1, a2 = _cross(h0, h1, h2, u0, u1, u2)
    b0, b1, b2 = _cross(h0, h1, h2, w0, w1, w2)
    return (xx * w0 + xy * w1 + xz * w2 + a0, xy * w0 + yy * w1 + yz * w2 + a1, xz * w0 + yz * w1 + zz * w2 + a2,
            m * u0 - b0, m * u1 - b1, m * u2 - b2)


@njit(cache=True, error_model="numpy")
def _add10(a, b):
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2], a[3] + b[3], a[4] + b[4], a[5] + b[5], a[6] + b[6],
            a[7] + b[7], a[8] + b[8], a[9] + b[9])


@njit(cache=True, error_model="numpy")
def _axis_rotation(x, y, z, angle):
    """Rotation by ``angle`` about the unit axis (x, y, z) (Rodrigues), as chain._axis_rotation."""
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return (c + t * x * x, t * x * y - s * z, t * x * z + s * y,
            t * x * y + s * z, c + t * y * y, t * y * z - s * x,
            t * x * z - s * y, t * y * z + s * x, c + t * z * z)


@njit(cache=True, error_model="numpy")
def _spatial_inertia(p, b, R, o):
    """Link (block ``b`` of p)'s spatial inertia at the origin in world axes, as chain._spatial_inertia:
    h = m c, Ibar = R Icom R^T + m (|c|^2 1 - c c^T), c = o + R com."""
    m = p[b + _MASS]
    r0, r1, r2 = _mv(R, p[b + _COM], p[b + _COM + 1], p[b + _COM + 2])
    c0, c1, c2 = o[0] + r0, o[1] + r1, o[2] + r2
    K = _get9(p, b + _INERTIA)
    T = _mm(R, K)  # R Icom; then (R Icom) R^T, its upper triangle
    xx = T[0] * R[0] + T[1] * R[1] + T[2] * R[2]
    xy = T[0] * R[3] + T[1] * R[4] + T[2] * R[5]
    xz = T[0] * R[6] + T[1] * R[7] + T[2] * R[8]
    yy = T[3] * R[3] + T[4] * R[4] + T[5] * R[5]
    yz = T[3] * R[6] + T[4] * R[7] + T[5] * R[8]
    zz = T[6] * R[6] + T[7] * R[7] + T[8] * R[8]
    cc = c0 * c0 + c1 * c1 + c2 * c2
    return (m, m * c0, m * c1, m * c2,
            xx + m * (cc - c0 * c0), xy - m * c0 * c1, xz - m * c0 * c2,
            yy + m * (cc - c1 * c1), yz - m * c1 * c2, zz + m * (cc - c2 * c2))


# --- the kernel ----------------------------------------------------------------------------------------

@njit(cache=True, error_model="numpy")
def terms(p, q, dq, level, out):
    """The chain's nd_dyn entries for the packed vector ``p`` (``chain.py``'s layout) at (q, dq), up to
    ``level``, into ``out`` (length >= :func:`width`); returns 1.0 (a chain has no working mode)."""
    n = int(p[0])
    e = int(p[1])
    op, oj, odjv, om, ob, ocq, og, odj, s = nd_layout(n, TASK)
    # --- frames and axes (chain.frames) ---
    Rp = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    o0, o1, o2 = 0.0, 0.0, 0.0
    for i in range(n):
        b = HEADER + LINK * i
        k = s + LINK_SCRATCH * i
        Rf = _mm(Rp, _get9(p, b + _ROT))  # the link frame at q = q0
        t0, t1, t2 = _mv(Rp, p[b + _POS], p[b + _POS + 1], p[b + _POS + 2])
        f0, f1, f2 = o0 + t0, o1 + t1, o2 + t2
        x, y, z = p[b + _AXIS], p[b + _AXIS + 1], p[b + _AXIS + 2]
        z0, z1, z2 = _mv(Rf, x, y, z)
        angle = q[i] - p[b + _Q0]
        if p[b + _TYPE] == HINGE:
            n0, n1, n2 = p[b + _ANCHOR], p[b + _ANCHOR + 1], p[b + _ANCHOR + 2]
            t0, t1, t2 = _mv(Rf, n0, n1, n2)
            a0, a1, a2 = f0 + t0, f1 + t1, f2 + t2
            Rp = _mm(Rf, _axis_rotation(x, y, z, angle))
            t0, t1, t2 = _mv(Rp, n0, n1, n2)
            o0, o1, o2 = a0 - t0, a1 - t1, a2 - t2
            c0, c1, c2 = _cross(a0, a1, a2, z0, z1, z2)
            _put6(out, k + _S, (z0, z1, z2, c0, c1, c2))
        else:
            Rp = Rf
            o0, o1, o2 = f0 + z0 * angle, f1 + z1 * angle, f2 + z2 * angle
            _put6(out, k + _S, (0.0, 0.0, 0.0, z0, z1, z2))
        _put9(out, k + _R, Rp)
        _put3(out, k + _O, (o0, o1, o2))
    # --- P and J (chain.forward_kinematics, chain.jacobian) ---
    ke = s + LINK_SCRATCH * e
    Re = _get9(out, ke + _R)
    t0, t1, t2 = _mv(Re, p[2], p[3], p[4])
    P0, P1, P2 = out[ke + _O] + t0, out[ke + _O + 1] + t1, out[ke + _O + 2] + t2
    _put3(out, op, (P0, P1, P2))
    for j in range(n):
        if j <= e:
            S = _get6(out, s + LINK_SCRATCH * j + _S)
            c0, c1, c2 = _cross(S[0], S[1], S[2], P0, P1, P2)
            out[oj + j], out[oj + n + j], out[oj + 2 * n + j] = c0 + S[3], c1 + S[4], c2 + S[5]
        else:
            out[oj + j], out[oj + n + j], out[oj + 2 * n + j] = 0.0, 0.0, 0.0
    if level < 1:
        return 1.0
    # --- rates, accelerations at ddq = 0 with the base at -g, link forces (chain._velocities_accelerations,
    # chain.inverse_dynamics' forward half) ---
    v = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    a = (0.0, 0.0, 0.0, -p[5], -p[6], -p[7])
    for i in range(n):
        k = s + LINK_SCRATCH * i
        S = _get6(out, k + _S)
        d = dq[i]
        v = (v[0] + S[0] * d, v[1] + S[1] * d, v[2] + S[2] * d, v[3] + S[3] * d, v[4] + S[4] * d, v[5] + S[5] * d)
        dS = _crm(v, S)  # dS_i/dt = v_i x S_i
        _put6(out, k + _DS, dS)
        a = (a[0] + dS[0] * d, a[1] + dS[1] * d, a[2] + dS[2] * d, a[3] + dS[3] * d, a[4] + dS[4] * d,
             a[5] + dS[5] * d)
        I = _spatial_inertia(p, HEADER + LINK * i, _get9(out, k + _R), _get3(out, k + _O))
        _put10(out, k + _I, I)
        Ia = _inertia_times(I, a)
        vIv = _crf(v, _inertia_times(I, v))
        _put6(out, k + _F, (Ia[0] + vIv[0], Ia[1] + vIv[1], Ia[2] + vIv[2], Ia[3] + vIv[3], Ia[4] + vIv[4],
                            Ia[5] + vIv[5]))
    # --- dJ/dt dq (chain.jacobian_derivative): column j = dw_j x P + w_j x dP + dv_j ---
    dP0, dP1, dP2 = 0.0, 0.0, 0.0
    for j in range(e + 1):
        d = dq[j]
        dP0 += out[oj + j] * d
        dP1 += out[oj + n + j] * d
        dP2 += out[oj + 2 * n + j] * d
    w0, w1, w2 = 0.0, 0.0, 0.0
    for j in range(n):
        if j <= e:
            k = s + LINK_SCRATCH * j
            S = _get6(out, k + _S)
            dS = _get6(out, k + _DS)
            a0, a1, a2 = _cross(dS[0], dS[1], dS[2], P0, P1, P2)
            b0, b1, b2 = _cross(S[0], S[1], S[2], dP0, dP1, dP2)
            c0, c1, c2 = a0 + b0 + dS[3], a1 + b1 + dS[4], a2 + b2 + dS[5]
        else:
            c0, c1, c2 = 0.0, 0.0, 0.0
        d = dq[j]
        w0 += c0 * d
        w1 += c1 * d
        w2 += c2 * d
        if level >= 2:
            out[odj + j], out[odj + n + j], out[odj + 2 * n + j] = c0, c1, c2
    _put3(out, odjv, (w0, w1, w2))
    # --- backwards: composite inertias, M (chain.joint_inertia), b = tau(q, dq, 0) with gravity ---
    Ic = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    F = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for j in range(n - 1, -1, -1):
        k = s + LINK_SCRATCH * j
        Ic = _add10(Ic, _get10(out, k + _I))
        _put10(out, k + _IC, Ic)
        f = _get6(out, k + _F)
        F = (F[0] + f[0], F[1] + f[1], F[2] + f[2], F[3] + f[3], F[4] + f[4], F[5] + f[5])
        S = _get6(out, k + _S)
        out[ob + j] = _dot6(S, F)
        IS = _inertia_times(Ic, S)
        _put6(out, k + _ICS, IS)
        for i in range(j + 1):
            value = _dot6(_get6(out, s + LINK_SCRATCH * i + _S), IS)
            out[om + i * n + j] = value
            out[om + j * n + i] = value
    if level < 2:
        return 1.0
    # --- g = S_i . (Ic_i a_0), a_0 = [0; -g] (every link at the base's acceleration when dq = 0) ---
    for i in range(n):
        k = s + LINK_SCRATCH * i
        Ig = _inertia_times(_get10(out, k + _IC), (0.0, 0.0, 0.0, -p[5], -p[6], -p[7]))
        out[og + i] = _dot6(_get6(out, k + _S), Ig)
    # --- dM/dq_k (chain.inertia_gradient) into the scratch after the links, then the Christoffel C ---
    od = s + LINK_SCRATCH * n
    for k in range(n):
        Sk = _get6(out, s + LINK_SCRATCH * k + _S)
        Ick = _get10(out, s + LINK_SCRATCH * k + _IC)
        for i in range(n):
            Si = _get6(out, s + LINK_SCRATCH * i + _S)
            ski = _crm(Sk, Si)
            for j in range(i, n):
                if k <= i:
                    value = 0.0
                elif k <= j:
                    value = -_dot6(ski, _get6(out, s + LINK_SCRATCH * j + _ICS))
                else:
                    Sj = _get6(out, s + LINK_SCRATCH * j + _S)
                    value = -_dot6(ski, _inertia_times(Ick, Sj)) - _dot6(_crm(Sk, Sj), _inertia_times(Ick, Si))
                out[od + (k * n + i) * n + j] = value
                out[od + (k * n + j) * n + i] = value
    for i in range(n):
        for j in range(n):
            total = 0.0
            for k in range(n):
                total += 0.5 * (out[od + (k * n + i) * n + j] + out[od + (j * n + i) * n + k]
                                - out[od + (i * n + j) * n + k]) * dq[k]
            out[ocq + i * n + j] = total
    return 1.0


# --- Slotine-Li's regressor (ilcforce.plants.adaptive), on the frames terms() left in ``work`` at level 0 -------

@njit(cache=True, error_model="numpy")
def jacobian_rate_times(p, dq, x, work):
    """dJ/dt x (world, a 3-tuple) at the (q, dq) whose level-0 entries ``work`` holds, as
    chain.jacobian_derivative: column j is dw_j x P + w_j x dP + dv_j with dS_j = v_j x S_j."""
    n = int(p[0])
    e = int(p[1])
    op, oj, _, _, _, _, _, _, s = nd_layout(n, TASK)
    P0, P1, P2 = work[op], work[op + 1], work[op + 2]
    dP0, dP1, dP2 = 0.0, 0.0, 0.0
    for j in range(e + 1):
        dP0 += work[oj + j] * dq[j]
        dP1 += work[oj + n + j] * dq[j]
        dP2 += work[oj + 2 * n + j] * dq[j]
    v = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    r0, r1, r2 = 0.0, 0.0, 0.0
    for j in range(e + 1):
        S = _get6(work, s + LINK_SCRATCH * j + _S)
        d = dq[j]
        v = (v[0] + S[0] * d, v[1] + S[1] * d, v[2] + S[2] * d, v[3] + S[3] * d, v[4] + S[4] * d, v[5] + S[5] * d)
        dS = _crm(v, S)
        a0, a1, a2 = _cross(dS[0], dS[1], dS[2], P0, P1, P2)
        b0, b1, b2 = _cross(S[0], S[1], S[2], dP0, dP1, dP2)
        r0 += (a0 + b0 + dS[3]) * x[j]
        r1 += (a1 + b1 + dS[4]) * x[j]
        r2 += (a2 + b2 + dS[5]) * x[j]
    return r0, r1, r2


@njit(cache=True, error_model="numpy")
def _to_link(R, o, m):
    """A world motion vector at the origin in link coordinates (at the link origin, in its axes), as chain._to_link."""
    c0, c1, c2 = _cross(m[0], m[1], m[2], o[0], o[1], o[2])
    a0, a1, a2 = R[0] * m[0] + R[3] * m[1] + R[6] * m[2], R[1] * m[0] + R[4] * m[1] + R[7] * m[2], \
        R[2] * m[0] + R[5] * m[1] + R[8] * m[2]
    u0, u1, u2 = m[3] + c0, m[4] + c1, m[5] + c2
    return (a0, a1, a2, R[0] * u0 + R[3] * u1 + R[6] * u2, R[1] * u0 + R[4] * u1 + R[7] * u2,
            R[2] * u0 + R[5] * u1 + R[8] * u2)


@njit(cache=True, error_model="numpy")
def _link_column(v, vr, a, c):
    """Column c of chain._link_regressor(v, vr, a) (a 6-tuple): the link force I(pi) a + v x* I(pi) vr per unit
    of its inertial parameter c (m, m c (3), Ixx Ixy Ixz Iyy Iyz Izz), link coordinates."""
    w0, w1, w2, u0, u1, u2 = v
    q0, q1, q2, r0, r1, r2 = vr  # wr, ur
    b0, b1, b2, l0, l1, l2 = a  # al, al_lin
    if c == 0:  # m: [u x ur; al_lin + w x ur]
        x0, x1, x2 = _cross(u0, u1, u2, r0, r1, r2)
        y0, y1, y2 = _cross(w0, w1, w2, r0, r1, r2)
        return x0, x1, x2, l0 + y0, l1 + y1, l2 + y2
    if c < 4:  # h_k: [e x al_lin + w x (e x ur) + u x (wr x e); al x e + w x (wr x e)]
        e0, e1, e2 = (1.0 if c == 1 else 0.0), (1.0 if c == 2 else 0.0), (1.0 if c == 3 else 0.0)
        x0, x1, x2 = _cross(e0, e1, e2, l0, l1, l2)
        t0, t1, t2 = _cross(e0, e1, e2, r0, r1, r2)
        y0, y1, y2 = _cross(w0, w1, w2, t0, t1, t2)
        t0, t1, t2 = _cross(q0, q1, q2, e0, e1, e2)
        z0, z1, z2 = _cross(u0, u1, u2, t0, t1, t2)
        f0, f1, f2 = _cross(b0, b1, b2, e0, e1, e2)
        g0, g1, g2 = _cross(w0, w1, w2, t0, t1, t2)
        return x0 + y0 + z0, x1 + y1 + z1, x2 + y2 + z2, f0 + g0, f1 + g1, f2 + g2
    # Ibar's entry: L(al) + w x L(wr), L(x) the column of Ibar x: xx (x0, 0, 0), xy (x1, x0, 0), xz (x2, 0, x0),
    # yy (0, x1, 0), yz (0, x2, x1), zz (0, 0, x2)
    if c == 4:
        a0, a1, a2, s0, s1, s2 = b0, 0.0, 0.0, q0, 0.0, 0.0
    elif c == 5:
        a0, a1, a2, s0, s1, s2 = b1, b0, 0.0, q1, q0, 0.0
    elif c == 6:
        a0, a1, a2, s0, s1, s2 = b2, 0.0, b0, q2, 0.0, q0
    elif c == 7:
        a0, a1, a2, s0, s1, s2 = 0.0, b1, 0.0, 0.0, q1, 0.0
    elif c == 8:
        a0, a1, a2, s0, s1, s2 = 0.0, b2, b1, 0.0, q2, q1
    else:
        a0, a1, a2, s0, s1, s2 = 0.0, 0.0, b2, 0.0, 0.0, q2
    y0, y1, y2 = _cross(w0, w1, w2, s0, s1, s2)
    return a0 + y0, a1 + y1, a2 + y2, 0.0, 0.0, 0.0


@njit(cache=True, error_model="numpy")
def slotine_li_regressor(p, dq, dq_r, ddq_r, work, Y, y0):
    """chain.slotine_li_regressor(p, q, dq, dq_r, ddq_r) (n x 10 n, row-major, into Y[y0:]) at the (q, dq) whose
    level-0 entries ``work`` holds: per unit of each of link l's ten parameters, the mean of Newton-Euler's link
    force on the reference motion seen at dq (I ar + v x* I vr) and at dq_r (I ar' + vr x* I v), projected on
    S_j (j <= l) in link l's coordinates. Allocates nothing."""
    n = int(p[0])
    s = nd_layout(n, TASK)[-1]
    width = N_INERTIAL * n
    for i in range(n * width):
        Y[y0 + i] = 0.0
    v = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    vr = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    ar = (0.0, 0.0, 0.0, -p[5], -p[6], -p[7])
    ar2 = ar
    for l in range(n):
        k = s + LINK_SCRATCH * l
        S = _get6(work, k + _S)
        d, dr, ddr = dq[l], dq_r[l], ddq_r[l]
        v = (v[0] + S[0] * d, v[1] + S[1] * d, v[2] + S[2] * d, v[3] + S[3] * d, v[4] + S[4] * d, v[5] + S[5] * d)
        vr = (vr[0] + S[0] * dr, vr[1] + S[1] * dr, vr[2] + S[2] * dr, vr[3] + S[3] * dr, vr[4] + S[4] * dr,
              vr[5] + S[5] * dr)
        dS = _crm(v, S)  # reference acceleration seen at dq: ar_l = ar_{l-1} + S_l ddq_r,l + (v_l x S_l) dq_r,l
        ar = (ar[0] + S[0] * ddr + dS[0] * dr, ar[1] + S[1] * ddr + dS[1] * dr, ar[2] + S[2] * ddr + dS[2] * dr,
              ar[3] + S[3] * ddr + dS[3] * dr, ar[4] + S[4] * ddr + dS[4] * dr, ar[5] + S[5] * ddr + dS[5] * dr)
        dS = _crm(vr, S)  # and at dq_r: ar'_l = ar'_{l-1} + S_l ddq_r,l + (vr_l x S_l) dq_l
        ar2 = (ar2[0] + S[0] * ddr + dS[0] * d, ar2[1] + S[1] * ddr + dS[1] * d, ar2[2] + S[2] * ddr + dS[2] * d,
               ar2[3] + S[3] * ddr + dS[3] * d, ar2[4] + S[4] * ddr + dS[4] * d, ar2[5] + S[5] * ddr + dS[5] * d)
        R = _get9(work, k + _R)
        o = _get3(work, k + _O)
        vb, vrb, arb, ar2b = _to_link(R, o, v), _to_link(R, o, vr), _to_link(R, o, ar), _to_link(R, o, ar2)
        for j in range(l + 1):
            Sj = _to_link(R, o, _get6(work, s + LINK_SCRATCH * j + _S))
            for c in range(N_INERTIAL):
                Y[y0 + j * width + N_INERTIAL * l + c] = 0.5 * (_dot6(Sj, _link_column(vb, vrb, arb, c))
                                                                + _dot6(Sj, _link_column(vrb, vb, ar2b, c)))


def _nd_kernel(address, q, dq, level, out):
    n = int(params_view(address, 1)[0])
    return terms(params_view(address, HEADER + LINK * n), q, dq, level, out)


@functools.cache
def kernel():
    """The chain's ``nd_dyn`` (numba dispatcher with ``ilcforce.plants.nd.nd_signature``), compiled or
    loaded from numba's cache on first call: any chain's, the packed vector at the address ``p``."""
    from ilcforce.plants import nd

    return nd.compile_nd(_nd_kernel)
