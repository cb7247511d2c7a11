"""The serial 2R arm in a vertical plane (docs/model.md#serial2r): the paper's n-DOF form with gravity.

theta1 is the absolute angle of link 1 from +x at the base joint (0, 0); theta2 the angle of link 2
relative to link 1. P = (L1 c1 + L2 c12, L1 s1 + L2 s12). Working mode: theta2 in (0, pi), i.e.
sin(theta2) > 0 ("elbow up" for a tip to the right of the base). Gravity g acts along -y.

Lagrangian model (Spong, Hutchinson & Vidyasagar, Robot Modeling and Control, section 7.4.2 form),
with Lci measured from link i's proximal joint and Ii centroidal:

    Dq = [[a + 2 b c2, d + b c2], [d + b c2, d]],  a = I1 + I2 + m1 Lc1^2 + m2 (L1^2 + Lc2^2),
                                                   b = m2 L1 Lc2,  d = I2 + m2 Lc2^2
    Cq = [[-h dth2, -h (dth1 + dth2)], [h dth1, 0]],  h = b s2      (Christoffel form: dDq - 2 Cq skew)
    G_q = g [(m1 Lc1 + m2 L1) c1 + m2 Lc2 c12, m2 Lc2 c12]
    Dq ddtheta + Cq dtheta + G_q = tau + J^T f                     (eq. 1, f the force on the robot)

Task space per eq. (4): D = J^-T Dq J^-1, C = J^-T (Cq - Dq J^-1 dJ) J^-1, G = J^-T G_q.

How the paper's task meets gravity on this arm (the decision behind ``experiments/serial2r.toml``):
the wall (y = 0.4 m) is above the base, so the task gravity G_y (10-15 N along the path; m2 x 1.4
adds 2.7-3.6 N) pulls the tool away from it, along the force-controlled axis, which has no
position feedback once contact is lost. With the five-bar's gains that axis has k_y lambda_F1 =
0.1 N/N of force authority and every method left the wall. The wall stays where the paper's task
puts it (so the two robots run one task); instead

* the learning methods keep the paper's laws and no gravity model, so they must learn G (C3 in
  Theta's G block, docs/model.md#serial2r), and the force axis is given the authority to hold the tool while they
  do: k_y = 5000 (C3, PD-ILC) or 1e4 (C2, C3-leak), i.e. 5-10 N of command per N of force error;
* C3's gravity gains are sized per axis: 100 on x (its position loop has k_x = 10) and 1000 on y;
* C3 takes the desired acceleration in Psi (``psi_acceleration = "desired"``, docs/model.md#acceleration): with the
  measured one and k_y = 5000 the noise it carries ran away after 21-25 iterations;
* C1 and SMC-BL carry the nominal G in their model and only need the stiffer axes (k = [100, 3000]).

Every learning method also has ``gravity_feedforward`` (add g_ff times the nominal G_nom; default 0,
the paper's laws). The shipped experiment does not use it: with it C2 starts at e_P 8e-5 m, e_F 0.24 N
(RMS, seed 0; 3.5e-3 m and 1.25 N without) and e_F improves less than 2x in 20 iterations, so the
experiment would no longer test the learning of G. SL-adapt starts from the nominal base parameters
(the gravity moments among them) and adapts them.
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
    task_from_dynamics,
    PackedParams,
    compile_kernels,
    Plant, PlantKernels,
    params_view,
)
from ilcforce.plants.nd import compile_nd, from_dyn

__all__ = ["Serial2RParams", "Serial2R", "PARAM_NAMES", "BASE_PARAMETER_NAMES", "BASE_PARAMETER_UNITS", "base_parameters", "regressor"]

#: Order of the packed parameter vector used by the compiled kernels.
PARAM_NAMES = ("L1", "L2", "Lc1", "Lc2", "m1", "m2", "I1", "I2", "g")


@dataclass(frozen=True)
class Serial2RParams(PackedParams):
    """Link parameters (docs/model.md#serial2r). Lengths in m, masses in kg, centroidal inertias in kg m^2,
    g in m/s^2 (>= 0; 0 turns gravity off)."""

    param_names = PARAM_NAMES  # packing order of as_array (not a field: no annotation)

    model: ClassVar[str] = "serial2r"  # the plants.MODELS key

    L1: float = 0.35  # link 1, m
    L2: float = 0.30  # link 2, m
    Lc1: float = 0.175  # base joint to link 1's centre of mass, m
    Lc2: float = 0.15  # elbow to link 2's centre of mass, m
    m1: float = 1.2  # kg
    m2: float = 0.9  # kg
    I1: float = 1.225e-2  # kg m^2
    I2: float = 6.75e-3  # kg m^2
    g: float = 9.81  # gravity along -y, m/s^2

    def __post_init__(self) -> None:
        for name in PARAM_NAMES:
            value = getattr(self, name)
            if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
                raise ValueError(f"plant.serial2r.{name} must be a number, got {value!r}")
            if not math.isfinite(value) or value < 0 or (value == 0 and name != "g"):
                raise ValueError(f"plant.serial2r.{name} must be finite and "
                                 f"{'>= 0' if name == 'g' else 'positive'}, got {value!r}")
            object.__setattr__(self, name, float(value))


    def mujoco_model(self):
        """The arm as MuJoCo simulates it (:class:`~ilcforce.plants.model_file.MujocoModel`): the shipped
        ``models/serial2r.xml`` with these lengths, centres of mass, masses, in-plane inertias and g; its plane is
        the file's x-z (the task's y is the model's z)."""
        from ilcforce.plants.model_file import MujocoModel, mujoco_spec

        spec = mujoco_spec("serial2r.xml")
        link1, link2 = spec.body("link1"), spec.body("link2")
        link1.mass, link1.ipos, link1.inertia = self.m1, [self.Lc1, 0.0, 0.0], [1e-4, self.I1, self.I1]
        link2.pos = [self.L1, 0.0, 0.0]
        link2.mass, link2.ipos, link2.inertia = self.m2, [self.Lc2, 0.0, 0.0], [1e-4, self.I2, self.I2]
        spec.site("tool").pos = [self.L2, 0.0, 0.0]
        return MujocoModel(spec, "tool", self.g, (), np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]))

_N_PARAMS = len(PARAM_NAMES)

# --------------------------------------------------------------------------------------------
# Compiled kernels. p is the packed parameter vector; everything else is a scalar.
# --------------------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy")
def _dynamics(p, th1, th2, d1, d2):
    """Joint-space model; returns the DYN tuple of ilcforce.plants.base (ok as 1.0 / 0.0)."""
    L1, L2, Lc1, Lc2, m1, m2, I1, I2, g = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7], p[8]
    c1, s1 = math.cos(th1), math.sin(th1)
    c2, s2 = math.cos(th2), math.sin(th2)
    c12, s12 = math.cos(th1 + th2), math.sin(th1 + th2)
    ok = 1.0 if s2 > 0.0 else 0.0  # working mode theta2 in (0, pi)
    px = L1 * c1 + L2 * c12
    py = L1 * s1 + L2 * s12
    J00 = -L1 * s1 - L2 * s12
    J01 = -L2 * s12
    J10 = L1 * c1 + L2 * c12
    J11 = L2 * c12
    w1 = d1
    w12 = d1 + d2
    dJ00 = -L1 * c1 * w1 - L2 * c12 * w12
    dJ01 = -L2 * c12 * w12
    dJ10 = -L1 * s1 * w1 - L2 * s12 * w12
    dJ11 = -L2 * s12 * w12
    a = I1 + I2 + m1 * Lc1 * Lc1 + m2 * (L1 * L1 + Lc2 * Lc2)
    b = m2 * L1 * Lc2
    d = I2 + m2 * Lc2 * Lc2
    Dq00 = a + 2.0 * b * c2
    Dq01 = d + b * c2
    Dq11 = d
    h = b * s2
    Cq00 = -h * d2
    Cq01 = -h * (d1 + d2)
    Cq10 = h * d1
    Cq11 = 0.0
    G2 = g * m2 * Lc2 * c12
    G1 = g * (m1 * Lc1 + m2 * L1) * c1 + G2
    return (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
            Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, G1, G2)


def _kin_kernel(address, th1, th2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    L1, L2 = p[0], p[1]
    c1, s1 = math.cos(th1), math.sin(th1)
    c12, s12 = math.cos(th1 + th2), math.sin(th1 + th2)
    ok = 1.0 if math.sin(th2) > 0.0 else 0.0
    return (ok, L1 * c1 + L2 * c12, L1 * s1 + L2 * s12,
            -L1 * s1 - L2 * s12, -L2 * s12, L1 * c1 + L2 * c12, L2 * c12)


def _accel_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, G1, G2) = _dynamics(p, th1, th2, d1, d2)
    det = Dq00 * Dq11 - Dq01 * Dq01
    b1 = Cq00 * d1 + Cq01 * d2 + G1
    b2 = Cq10 * d1 + Cq11 * d2 + G2
    return (ok, px, py, J00, J01, J10, J11, dJ00 * d1 + dJ01 * d2, dJ10 * d1 + dJ11 * d2, b1, b2,
            Dq11 / det, -Dq01 / det, Dq00 / det)


def _task_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    return task_from_dynamics(_dynamics(p, th1, th2, d1, d2), d1, d2)  # eq. (4)


def _dyn_kernel(address, th1, th2, d1, d2):
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    return _dynamics(p, th1, th2, d1, d2)


def _ik_kernel(address, px, py):
    """theta2 = acos(c2) in (0, pi); theta1 = atan2(y, x) - atan2(L2 s2, L1 + L2 c2)."""
    p = params_view(address, _N_PARAMS)  # the kernels take the vector's address
    L1, L2 = p[0], p[1]
    c2 = (px * px + py * py - L1 * L1 - L2 * L2) / (2.0 * L1 * L2)
    if not (-1.0 < c2 < 1.0):
        return (0.0, math.nan, math.nan)
    th2 = math.acos(c2)
    th1 = math.atan2(py, px) - math.atan2(L2 * math.sin(th2), L1 + L2 * c2)
    return (1.0, th1, th2)


#: the DYN kernel as compiled code calls it (the n-joint kernel's source; the same function, options and cache)
_dyn_compiled = njit(cache=True, error_model="numpy")(_dyn_kernel)


def _nd_kernel(address, q, dq, level, out):
    """The n-joint interface's ``nd_dyn`` (ilcforce.plants.nd, n = 2) from the DYN kernel."""
    return from_dyn(_dyn_compiled(address, q[0], q[1], dq[0], dq[1]), dq[0], dq[1], level, out)


@functools.cache
def nd_kernel():
    """The 2R arm's ``nd_dyn`` (compiled, or loaded from numba's cache, on first call)."""
    return compile_nd(_nd_kernel)


@functools.cache
def kernels() -> PlantKernels:
    """The 2R arm's interface kernels (compiled, or loaded from numba's cache, on first call)."""
    return compile_kernels(_kin_kernel, _accel_kernel, _task_kernel, _dyn_kernel, _ik_kernel)


class Serial2R(Plant):
    """The serial 2R arm with parameters ``params`` (docs/model.md#serial2r), gravity along -y."""

    params_class = Serial2RParams
    working_mode = "the working mode theta2 in (0, pi)"
    has_gravity = True
    kernels = staticmethod(kernels)
    nd_kernel = staticmethod(nd_kernel)

    def potential_energy(self, theta) -> float:
        """V = g (m1 Lc1 s1 + m2 (L1 s1 + Lc2 s12)) (J), zero at y = 0."""
        th1, th2 = (float(v) for v in np.asarray(theta, dtype=np.float64))
        pr = self.params
        return pr.g * (pr.m1 * pr.Lc1 * math.sin(th1) + pr.m2 * (pr.L1 * math.sin(th1) + pr.Lc2 * math.sin(th1 + th2)))


# --------------------------------------------------------------------------------------------
# Linear parametrisation (Slotine & Li 1987): Dq(q) ddq_r + Cq(q, dq) dq_r + G_q(q) = Y(q, dq, dq_r, ddq_r) a
# --------------------------------------------------------------------------------------------

#: The base parameters a, constant for a given arm (the model's a, b, d and the two gravity moments).
BASE_PARAMETER_NAMES = ("a", "b", "d", "g1", "g2")
#: their units, as an adaptive law's memory describes them
BASE_PARAMETER_UNITS = "kg m^2 (a, b, d), N m (g1, g2)"


def base_parameters(params: Serial2RParams) -> np.ndarray:
    """a = (I1 + I2 + m1 Lc1^2 + m2 (L1^2 + Lc2^2), m2 L1 Lc2, I2 + m2 Lc2^2, g (m1 Lc1 + m2 L1), g m2 Lc2),
    shape (5,): kg m^2, kg m^2, kg m^2, N m, N m."""
    p = params
    return np.array([p.I1 + p.I2 + p.m1 * p.Lc1 ** 2 + p.m2 * (p.L1 ** 2 + p.Lc2 ** 2), p.m2 * p.L1 * p.Lc2,
                     p.I2 + p.m2 * p.Lc2 ** 2, p.g * (p.m1 * p.Lc1 + p.m2 * p.L1), p.g * p.m2 * p.Lc2])


@njit(cache=True, error_model="numpy")
def regressor(p, th1, th2, d1, d2, r1, r2, rr1, rr2):
    """Y(q, dq, dq_r, ddq_r), shape (2, 6) as a tuple (row 0, then row 1), so that Y a (a:
    :func:`base_parameters`, padded with a 0) = Dq ddq_r + Cq(q, dq) dq_r + G_q. The sixth column is 0
    (this arm has five base parameters; the five-bar six). ``p`` (the packed parameters) is not read:
    this arm's regressor depends on the joint state alone; it is there for one signature per plant."""
    c1 = math.cos(th1)
    c2, s2 = math.cos(th2), math.sin(th2)
    c12 = math.cos(th1 + th2)
    y01 = 2.0 * c2 * rr1 + c2 * rr2 - s2 * d2 * r1 - s2 * (d1 + d2) * r2  # the b column, joint 1
    y11 = c2 * rr1 + s2 * d1 * r1  # the b column, joint 2
    return (rr1, y01, rr2, c1, c12, 0.0,
            0.0, y11, rr1 + rr2, 0.0, c12, 0.0)
