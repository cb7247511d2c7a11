"""The five-bar parallel manipulator of the paper's Section 4.1 (docs/model.md#fivebar).

Two layers (the plant interface of ``ilcforce.plants.base``):

* compiled kernels (``_kinematics``, ``_dynamics``, ...): scalar numba functions taking the packed
  parameter vector from :meth:`FiveBarParams.as_array` and returning tuples. They allocate nothing,
  so the simulation loop can call them four times per RK4 step. :func:`kernels` wraps them in the
  interface's fixed signatures (compiled or loaded from numba's cache on first use only).
* :class:`FiveBar`: the readable, checked public API on single samples, returning numpy arrays of
  shape (2,) or (2, 2) in SI units (shared with every plant through :class:`Plant`), plus the
  passive-link angles.

Geometry. Base joints B1 = (0, 0) and B2 = (L5, 0). theta1 and theta2 are the absolute angles of
links 1 and 2 from +x. Link 3 joins the tip E1 of link 1 to the end-effector P, link 4 the tip E2 of
link 2 to P. phi3 and phi4 are the absolute angles of links 3 and 4 (passive). Working mode
"elbows out": E1 left of P - B1, E2 right of P - B2; P is the circle intersection to the left of
E1 -> E2.

Dynamics. The open tree q' = (theta1, theta2, phi3, phi4) has the inertia matrix M(q') and the
Christoffel Coriolis matrix C'(q', dq'). The loop closure E1 + L3 e(phi3) = E2 + L4 e(phi4) gives
dq' = rho dtheta with rho = [I; R], R = d phi / d theta. The actuated-joint model is then

    Dq = rho^T M rho,   Cq = rho^T (M drho + C' rho)                     (eq. 1, G_q = 0)
    Dq ddtheta + Cq dtheta = tau + J^T f                                  (f: force on the robot)

and in task space (eq. 4) D = J^-T Dq J^-1, C = J^-T (Cq - Dq J^-1 dJ) J^-1. With this Cq,
dDq/dt - 2 Cq is skew-symmetric (property P2), and so is dD/dt - 2 C.
"""

from __future__ import annotations

import functools
import math
import numbers
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.plants.base import (
    task_space,
    PackedParams,
    compile_kernels,
    Plant, PlantKernels,
    params_view,
    UnreachableError, check_pair as _pair,
)
from ilcforce.plants.nd import compile_nd, from_dyn

__all__ = ["FiveBarParams", "FiveBar", "UnreachableError", "PARAM_NAMES", "BASE_PARAMETER_NAMES", "BASE_PARAMETER_UNITS", "base_parameters",
           "regressor"]

#: Order of the packed parameter vector used by the compiled kernels.
PARAM_NAMES = (
    "L1", "L2", "L3", "L4", "L5",
    "Lc1", "Lc2", "Lc3", "Lc4",
    "m1", "m2", "m3", "m4",
    "I1", "I2", "I3", "I4",
)


@dataclass(frozen=True)
class FiveBarParams(PackedParams):
    """Link parameters (Table 1). Lengths in m, masses in kg, centroidal inertias in kg m^2.

    ``Lci`` is measured from link i's proximal joint (B1, B2, E1, E2) to its centre of mass.
    """

    param_names = PARAM_NAMES  # packing order of as_array (not a field: no annotation)

    model: ClassVar[str] = "fivebar"  # the plants.MODELS key

    L1: float = 0.2794  # link 1 (actuated, at B1), m
    L2: float = 0.2794  # link 2 (actuated, at B2), m
    L3: float = 0.3048  # link 3 (E1 to P), m
    L4: float = 0.3048  # link 4 (E2 to P), m
    L5: float = 0.3048  # base, distance B1 to B2, m
    Lc1: float = 0.1466  # m
    Lc2: float = 0.1410  # m
    Lc3: float = 0.1581  # m
    Lc4: float = 0.1467  # m
    m1: float = 0.2451  # kg
    m2: float = 0.2352  # kg
    m3: float = 0.2611  # kg
    m4: float = 0.2611  # kg
    I1: float = 2.779e-3  # kg m^2
    I2: float = 2.607e-3  # kg m^2
    I3: float = 3.476e-3  # kg m^2
    I4: float = 3.476e-3  # kg m^2

    def __post_init__(self) -> None:
        for name in PARAM_NAMES:
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
                raise ValueError(f"plant.fivebar.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"plant.fivebar.{name} must be finite and positive, got {value!r}")
            object.__setattr__(self, name, float(value))  # numpy scalars become plain floats


    def links(self) -> "FiveBarParams":
        """Just the link parameters, as a plain :class:`FiveBarParams`."""
        return FiveBarParams(**{name: getattr(self, name) for name in PARAM_NAMES})

_N_PARAMS = len(PARAM_NAMES)

# --------------------------------------------------------------------------------------------
# Compiled kernels. p is the packed parameter vector; everything else is a scalar.
# --------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _kinematics(p, th1, th2):
    """Forward kinematics with the loop-closure Jacobian.

    Returns (ok, Px, Py, u3x, u3y, u4x, u4y, R00, R01, R10, R11, J00, J01, J10, J11), where
    u3 = (cos phi3, sin phi3), u4 likewise, R = d(phi3, phi4)/d(theta1, theta2) and J = dP/dtheta.
    ``ok`` is False (and the rest NaN) when the pose is outside the elbows-out working mode.
    """
    L1, L2, L3, L4, L5 = p[0], p[1], p[2], p[3], p[4]
    c1, s1 = math.cos(th1), math.sin(th1)
    c2, s2 = math.cos(th2), math.sin(th2)
    e1x, e1y = L1 * c1, L1 * s1
    e2x, e2y = L5 + L2 * c2, L2 * s2
    dx, dy = e2x - e1x, e2y - e1y
    r2 = dx * dx + dy * dy
    r = math.sqrt(r2)
    a = (L3 * L3 - L4 * L4 + r2) / (2.0 * r)
    h2 = L3 * L3 - a * a
    nan = math.nan
    if not (h2 > 0.0):
        return (False, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    h = math.sqrt(h2)
    # circle intersection to the left of E1 -> E2 (the upper assembly)
    px = e1x + (a * dx - h * dy) / r
    py = e1y + (a * dy + h * dx) / r
    # elbows out: E1 left of P - B1, E2 right of P - B2
    if px * e1y - py * e1x <= 0.0 or (px - L5) * e2y - py * (e2x - L5) >= 0.0:
        return (False, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan)
    u3x, u3y = (px - e1x) / L3, (py - e1y) / L3
    u4x, u4y = (px - e2x) / L4, (py - e2y) / L4
    # loop closure, differentiated: A dphi = B dtheta with
    # A = [L3 e_perp(phi3), -L4 e_perp(phi4)], B = [-L1 e_perp(theta1), L2 e_perp(theta2)]
    a11, a21 = -L3 * u3y, L3 * u3x
    a12, a22 = L4 * u4y, -L4 * u4x
    b11, b21 = L1 * s1, -L1 * c1
    b12, b22 = -L2 * s2, L2 * c2
    det = a11 * a22 - a12 * a21
    R00 = (a22 * b11 - a12 * b21) / det
    R01 = (a22 * b12 - a12 * b22) / det
    R10 = (a11 * b21 - a21 * b11) / det
    R11 = (a11 * b22 - a21 * b12) / det
    # P = E1 + L3 u3  =>  dP = L1 e_perp(theta1) dtheta1 + L3 e_perp(phi3) dphi3
    J00 = -L1 * s1 - L3 * u3y * R00
    J01 = -L3 * u3y * R01
    J10 = L1 * c1 + L3 * u3x * R00
    J11 = L3 * u3x * R01
    return (True, px, py, u3x, u3y, u4x, u4y, R00, R01, R10, R11, J00, J01, J10, J11)


@njit(cache=True, error_model="numpy")
def _dynamics(p, th1, th2, dth1, dth2):
    """Joint-space model terms at (theta, dtheta).

    Returns (ok, Px, Py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
             Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11).
    """
    (ok, px, py, u3x, u3y, u4x, u4y, R00, R01, R10, R11,
     J00, J01, J10, J11) = _kinematics(p, th1, th2)
    L1, L2, L3, L4 = p[0], p[1], p[2], p[3]
    Lc1, Lc2, Lc3, Lc4 = p[5], p[6], p[7], p[8]
    m1, m2, m3, m4 = p[9], p[10], p[11], p[12]
    I1, I2, I3, I4 = p[13], p[14], p[15], p[16]
    c1, s1 = math.cos(th1), math.sin(th1)
    c2, s2 = math.cos(th2), math.sin(th2)
    # passive rates
    dph3 = R00 * dth1 + R01 * dth2
    dph4 = R10 * dth1 + R11 * dth2
    # open-tree inertia (order theta1, theta2, phi3, phi4); cos/sin of theta - phi
    M11 = I1 + m1 * Lc1 * Lc1 + m3 * L1 * L1
    M22 = I2 + m2 * Lc2 * Lc2 + m4 * L2 * L2
    M33 = I3 + m3 * Lc3 * Lc3
    M44 = I4 + m4 * Lc4 * Lc4
    k3 = m3 * L1 * Lc3
    k4 = m4 * L2 * Lc4
    M13 = k3 * (c1 * u3x + s1 * u3y)
    M24 = k4 * (c2 * u4x + s2 * u4y)
    sn13 = s1 * u3x - c1 * u3y  # sin(theta1 - phi3)
    sn24 = s2 * u4x - c2 * u4y  # sin(theta2 - phi4)
    # Dq = rho^T M rho, rho = [[1, 0], [0, 1], [R00, R01], [R10, R11]]
    Dq00 = M11 + 2.0 * M13 * R00 + M33 * R00 * R00 + M44 * R10 * R10
    Dq01 = M13 * R01 + M24 * R10 + M33 * R00 * R01 + M44 * R10 * R11
    Dq11 = M22 + 2.0 * M24 * R11 + M33 * R01 * R01 + M44 * R11 * R11
    # dR = A^-1 (dB - dA R)
    a11, a21 = -L3 * u3y, L3 * u3x
    a12, a22 = L4 * u4y, -L4 * u4x
    det = a11 * a22 - a12 * a21
    db11, db21 = L1 * dth1 * c1, L1 * dth1 * s1
    db12, db22 = -L2 * dth2 * c2, -L2 * dth2 * s2
    da11, da21 = -L3 * dph3 * u3x, -L3 * dph3 * u3y
    da12, da22 = L4 * dph4 * u4x, L4 * dph4 * u4y
    w11 = db11 - (da11 * R00 + da12 * R10)
    w12 = db12 - (da11 * R01 + da12 * R11)
    w21 = db21 - (da21 * R00 + da22 * R10)
    w22 = db22 - (da21 * R01 + da22 * R11)
    dR00 = (a22 * w11 - a12 * w21) / det
    dR01 = (a22 * w12 - a12 * w22) / det
    dR10 = (a11 * w21 - a21 * w11) / det
    dR11 = (a11 * w22 - a21 * w12) / det
    # Cq = rho^T M drho + rho^T C' rho, with C'[th1, ph3] = k3 sn13 dph3, C'[ph3, th1] = -k3 sn13 dth1
    # (and the same pattern for theta2 / phi4)
    # M drho, drho = [[0, 0], [0, 0], [dR00, dR01], [dR10, dR11]]
    Md_0j0 = M13 * dR00
    Md_0j1 = M13 * dR01
    Md_1j0 = M24 * dR10
    Md_1j1 = M24 * dR11
    Md_2j0 = M33 * dR00
    Md_2j1 = M33 * dR01
    Md_3j0 = M44 * dR10
    Md_3j1 = M44 * dR11
    # C' rho
    g3 = k3 * sn13
    g4 = k4 * sn24
    Cr_0j0 = g3 * dph3 * R00
    Cr_0j1 = g3 * dph3 * R01
    Cr_1j0 = g4 * dph4 * R10
    Cr_1j1 = g4 * dph4 * R11
    Cr_2j0 = -g3 * dth1
    Cr_2j1 = 0.0
    Cr_3j0 = 0.0
    Cr_3j1 = -g4 * dth2
    X0j0 = Md_0j0 + Cr_0j0
    X0j1 = Md_0j1 + Cr_0j1
    X1j0 = Md_1j0 + Cr_1j0
    X1j1 = Md_1j1 + Cr_1j1
    X2j0 = Md_2j0 + Cr_2j0
    X2j1 = Md_2j1 + Cr_2j1
    X3j0 = Md_3j0 + Cr_3j0
    X3j1 = Md_3j1 + Cr_3j1
    Cq00 = X0j0 + R00 * X2j0 + R10 * X3j0
    Cq01 = X0j1 + R00 * X2j1 + R10 * X3j1
    Cq10 = X1j0 + R01 * X2j0 + R11 * X3j0
    Cq11 = X1j1 + R01 * X2j1 + R11 * X3j1
    # dJ from J = [L1 e_perp(th1), 0] + L3 e_perp(phi3) R[0, :]
    dJ00 = -L1 * c1 * dth1 + L3 * (-dph3 * u3x * R00 - u3y * dR00)
    dJ01 = L3 * (-dph3 * u3x * R01 - u3y * dR01)
    dJ10 = -L1 * s1 * dth1 + L3 * (-dph3 * u3y * R00 + u3x * dR00)
    dJ11 = L3 * (-dph3 * u3y * R01 + u3x * dR01)
    return (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
            Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11)


@njit(cache=True, error_model="numpy")
def _task_model(p, th1, th2, dth1, dth2):
    """Task-space model (eq. 4) at (theta, dtheta).

    Returns (ok, Px, Py, vx, vy, J00, J01, J10, J11, D00, D01, D11, C00, C01, C10, C11).
    """
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11) = _dynamics(p, th1, th2, dth1, dth2)
    vx = J00 * dth1 + J01 * dth2
    vy = J10 * dth1 + J11 * dth2
    D00, D01, D11, C00, C01, C10, C11, _Ji00, _Ji01, _Ji10, _Ji11 = task_space(
        J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11)  # eq. (4)
    return (ok, px, py, vx, vy, J00, J01, J10, J11, D00, D01, D11, C00, C01, C10, C11)


@njit(cache=True, error_model="numpy")
def _inverse_kinematics(p, px, py):
    """Elbows-out inverse kinematics. Returns (ok, theta1, theta2)."""
    L1, L2, L3, L4, L5 = p[0], p[1], p[2], p[3], p[4]
    r1 = math.hypot(px, py)
    r2 = math.hypot(px - L5, py)
    if r1 == 0.0 or r2 == 0.0:
        return (False, math.nan, math.nan)
    c_a = (L1 * L1 + r1 * r1 - L3 * L3) / (2.0 * L1 * r1)
    c_b = (L2 * L2 + r2 * r2 - L4 * L4) / (2.0 * L2 * r2)
    if not (-1.0 < c_a < 1.0) or not (-1.0 < c_b < 1.0):
        return (False, math.nan, math.nan)
    th1 = math.atan2(py, px) + math.acos(c_a)
    th2 = math.atan2(py, px - L5) - math.acos(c_b)
    return (True, th1, th2)


@njit(cache=True, error_model="numpy")
def _accel_terms(p, th1, th2, dth1, dth2):
    """Forward dynamics as an affine map of the generalised force.

    Dq ddtheta + Cq dtheta = tau + J^T f  =>  ddtheta = Dq^-1 (tau + J^T f - Cq dtheta).
    Returns (ok, Px, Py, J00, J01, J10, J11, dJv_x, dJv_y, b1, b2, Mi00, Mi01, Mi11) with
    b = Cq dtheta, dJv = dJ dtheta (so ddP = J ddtheta + dJv) and Mi = Dq^-1 (symmetric).
    """
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11) = _dynamics(p, th1, th2, dth1, dth2)
    det = Dq00 * Dq11 - Dq01 * Dq01
    Mi00, Mi01, Mi11 = Dq11 / det, -Dq01 / det, Dq00 / det
    b1 = Cq00 * dth1 + Cq01 * dth2
    b2 = Cq10 * dth1 + Cq11 * dth2
    dJvx = dJ00 * dth1 + dJ01 * dth2
    dJvy = dJ10 * dth1 + dJ11 * dth2
    return (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, b1, b2, Mi00, Mi01, Mi11)


# --------------------------------------------------------------------------------------------
# The plant interface's kernels (ilcforce.plants.base), compiled on first use.
# --------------------------------------------------------------------------------------------


def _kin_kernel(address, th1, th2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    out = _kinematics(p, th1, th2)
    return (1.0 if out[0] else 0.0, out[1], out[2], out[11], out[12], out[13], out[14])


def _accel_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    (ok, px, py, J00, J01, J10, J11, dJvx, dJvy, b1, b2, Mi00, Mi01, Mi11) = _accel_terms(p, th1, th2, d1, d2)
    # G_q = 0 (horizontal plane): b = Cq dtheta
    return (1.0 if ok else 0.0, px, py, J00, J01, J10, J11, dJvx, dJvy, b1, b2, Mi00, Mi01, Mi11)


def _task_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    (ok, px, py, vx, vy, J00, J01, J10, J11, D00, D01, D11,
     C00, C01, C10, C11) = _task_model(p, th1, th2, d1, d2)
    return (1.0 if ok else 0.0, px, py, vx, vy, J00, J01, J10, J11, D00, D01, D11, C00, C01, C10, C11, 0.0, 0.0)


def _dyn_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11) = _dynamics(p, th1, th2, d1, d2)
    return (1.0 if ok else 0.0, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
            Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, 0.0, 0.0)


def _ik_kernel(address, px, py):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    ok, th1, th2 = _inverse_kinematics(p, px, py)
    return (1.0 if ok else 0.0, th1, th2)


#: the DYN kernel as compiled code calls it (the n-joint kernel's source; the same function, options and cache)
_dyn_compiled = njit(cache=True, error_model="numpy")(_dyn_kernel)


def _nd_kernel(address, q, dq, level, out):
    """The n-joint interface's ``nd_dyn`` (ilcforce.plants.nd, n = 2) from the DYN kernel."""
    return from_dyn(_dyn_compiled(address, q[0], q[1], dq[0], dq[1]), dq[0], dq[1], level, out)


@functools.cache
def nd_kernel():
    """The five-bar's ``nd_dyn`` (compiled, or loaded from numba's cache, on first call)."""
    return compile_nd(_nd_kernel)


@functools.cache
def kernels() -> PlantKernels:
    """The five-bar's interface kernels (compiled, or loaded from numba's cache, on first call)."""
    return compile_kernels(_kin_kernel, _accel_kernel, _task_kernel, _dyn_kernel, _ik_kernel)


# --------------------------------------------------------------------------------------------
# Public, checked API on single samples.
# --------------------------------------------------------------------------------------------


class FiveBar(Plant):
    """The five-bar manipulator with parameters ``params`` (docs/model.md#fivebar), G_q = 0.

    All methods take and return numpy arrays: joint vectors (theta1, theta2) of shape (2,),
    task vectors (x, y) of shape (2,), matrices of shape (2, 2). SI units throughout.
    """

    params_class = FiveBarParams
    working_mode = "the elbows-out working mode"
    has_gravity = False
    kernels = staticmethod(kernels)
    nd_kernel = staticmethod(nd_kernel)

    def passive_angles(self, theta) -> np.ndarray:
        """Absolute angles (phi3, phi4) of the passive links 3 and 4 (rad)."""
        th1, th2 = _pair("theta", theta)
        out = _kinematics(self._p, th1, th2)
        if not out[0]:
            raise self._outside(th1, th2)
        return np.array([math.atan2(out[4], out[3]), math.atan2(out[6], out[5])])

    def passive_jacobian(self, theta) -> np.ndarray:
        """R = d(phi3, phi4) / d(theta1, theta2), shape (2, 2)."""
        th1, th2 = _pair("theta", theta)
        out = _kinematics(self._p, th1, th2)
        if not out[0]:
            raise self._outside(th1, th2)
        return np.array([[out[7], out[8]], [out[9], out[10]]])


# --------------------------------------------------------------------------------------------
# Linear parametrisation (Slotine & Li 1987): Dq(q) ddq_r + Cq(q, dq) dq_r = Y(q, dq, dq_r, ddq_r) a
# --------------------------------------------------------------------------------------------

#: The base parameters a: the open tree's inertia entries M11, M22, M33, M44 and the couplings
#: k3 = m3 L1 Lc3, k4 = m4 L2 Lc4 (Dq and Cq are linear in them for given lengths; see _dynamics).
BASE_PARAMETER_NAMES = ("M11", "M22", "M33", "M44", "k3", "k4")
#: their units, as an adaptive law's memory describes them
BASE_PARAMETER_UNITS = "kg m^2"


def base_parameters(params: FiveBarParams) -> np.ndarray:
    """a = (I1 + m1 Lc1^2 + m3 L1^2, I2 + m2 Lc2^2 + m4 L2^2, I3 + m3 Lc3^2, I4 + m4 Lc4^2,
    m3 L1 Lc3, m4 L2 Lc4), shape (6,), kg m^2."""
    p = params
    return np.array([p.I1 + p.m1 * p.Lc1 ** 2 + p.m3 * p.L1 ** 2, p.I2 + p.m2 * p.Lc2 ** 2 + p.m4 * p.L2 ** 2,
                     p.I3 + p.m3 * p.Lc3 ** 2, p.I4 + p.m4 * p.Lc4 ** 2, p.m3 * p.L1 * p.Lc3, p.m4 * p.L2 * p.Lc4])


@njit(cache=True, error_model="numpy")
def regressor(p, th1, th2, dth1, dth2, r1, r2, rr1, rr2):
    """Y(q, dq, dq_r, ddq_r), shape (2, 6) as a tuple (row 0, then row 1), with Y a (a:
    :func:`base_parameters`) = Dq ddq_r + Cq(q, dq) dq_r, Dq and Cq as in :func:`_dynamics`
    (rho = [I; R]): each column is the part of Dq ddq_r + Cq dq_r one base parameter multiplies."""
    (ok, px, py, u3x, u3y, u4x, u4y, R00, R01, R10, R11,
     J00, J01, J10, J11) = _kinematics(p, th1, th2)
    L1, L2, L3, L4 = p[0], p[1], p[2], p[3]
    c1, s1 = math.cos(th1), math.sin(th1)
    c2, s2 = math.cos(th2), math.sin(th2)
    dph3 = R00 * dth1 + R01 * dth2
    dph4 = R10 * dth1 + R11 * dth2
    cos13 = c1 * u3x + s1 * u3y  # cos(theta1 - phi3): M13 = k3 cos13
    cos24 = c2 * u4x + s2 * u4y
    sn13 = s1 * u3x - c1 * u3y  # sin(theta1 - phi3)
    sn24 = s2 * u4x - c2 * u4y
    # dR = A^-1 (dB - dA R), as in _dynamics
    a11, a21 = -L3 * u3y, L3 * u3x
    a12, a22 = L4 * u4y, -L4 * u4x
    det = a11 * a22 - a12 * a21
    db11, db21 = L1 * dth1 * c1, L1 * dth1 * s1
    db12, db22 = -L2 * dth2 * c2, -L2 * dth2 * s2
    da11, da21 = -L3 * dph3 * u3x, -L3 * dph3 * u3y
    da12, da22 = L4 * dph4 * u4x, L4 * dph4 * u4y
    w11 = db11 - (da11 * R00 + da12 * R10)
    w12 = db12 - (da11 * R01 + da12 * R11)
    w21 = db21 - (da21 * R00 + da22 * R10)
    w22 = db22 - (da21 * R01 + da22 * R11)
    dR00 = (a22 * w11 - a12 * w21) / det
    dR01 = (a22 * w12 - a12 * w22) / det
    dR10 = (a11 * w21 - a21 * w11) / det
    dR11 = (a11 * w22 - a21 * w12) / det
    r3_acc = R00 * rr1 + R01 * rr2  # r3 . ddq_r, r3 = R's phi3 row
    r4_acc = R10 * rr1 + R11 * rr2
    r3_vel = R00 * r1 + R01 * r2
    r4_vel = R10 * r1 + R11 * r2
    dr3_vel = dR00 * r1 + dR01 * r2
    dr4_vel = dR10 * r1 + dR11 * r2
    m33 = r3_acc + dr3_vel  # M33: Dq gains r3 r3^T, Cq gains r3 dR3^T
    m44 = r4_acc + dr4_vel
    # k3: Dq gains cos13 (e0 r3^T + r3 e0^T); Cq gains e0 (cos13 dR3 + sn13 dph3 r3)^T - sn13 dth1 r3 e0^T
    k3_row0 = cos13 * (r3_acc + R00 * rr1) + cos13 * dr3_vel + sn13 * dph3 * r3_vel - R00 * sn13 * dth1 * r1
    k3_row1 = cos13 * R01 * rr1 - R01 * sn13 * dth1 * r1
    k4_row0 = cos24 * R10 * rr2 - R10 * sn24 * dth2 * r2
    k4_row1 = cos24 * (r4_acc + R11 * rr2) + cos24 * dr4_vel + sn24 * dph4 * r4_vel - R11 * sn24 * dth2 * r2
    return (rr1, 0.0, R00 * m33, R10 * m44, k3_row0, k4_row0,
            0.0, rr2, R01 * m33, R11 * m44, k3_row1, k4_row1)
