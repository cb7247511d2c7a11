"""The one interface every plant implements (compiled kernels + the checked public API).

Compiled kernels
----------------
The simulation loop calls a plant only through numba first-class function pointers with the fixed
signatures below (as it calls control laws, ``ilcforce.controllers.nd.law_signature``), so the loop is
compiled once for every plant. Every kernel takes the plant's packed parameter vector ``p`` and
scalars, allocates nothing, and returns a tuple of floats whose first entry ``ok`` is 1.0, or 0.0
(the rest NaN or meaningless) when the pose is outside the plant's working mode:

* ``kin(p, th1, th2)`` -> (ok, Px, Py, J00, J01, J10, J11)                       :data:`KIN_TYPE`
* ``accel(p, th1, th2, d1, d2)`` -> (ok, Px, Py, J00, J01, J10, J11, dJv_x, dJv_y, b1, b2,
  Mi00, Mi01, Mi11) with b = Cq dtheta + G_q, dJv = dJ dtheta, Mi = Dq^-1, i.e. forward dynamics
  ddtheta = Mi (tau + J^T f - b) as an affine map of the generalised force (eq. 1)  :data:`ACCEL_TYPE`
* ``task(p, th1, th2, d1, d2)`` -> (ok, Px, Py, vx, vy, J00, J01, J10, J11, D00, D01, D11,
  C00, C01, C10, C11, Gx, Gy): the task-space model of eq. (4) with G = J^-T G_q     :data:`TASK_TYPE`
* ``dyn(p, th1, th2, d1, d2)`` -> (ok, Px, Py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
  Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, Gq1, Gq2): the joint-space model      :data:`DYN_TYPE`
* ``ik(p, Px, Py)`` -> (ok, th1, th2): inverse kinematics in the working mode       :data:`IK_TYPE`

``p`` is the *address* of the packed parameter vector (``array.ctypes.data``), viewed inside a
kernel with :func:`params_view`: passing a numba array through a function pointer costs about
20-40 ns a call (its meminfo is reference-counted in the call wrapper), a raw address nothing, and
the loop makes five such calls per control step.

A plant module exposes them lazily through :meth:`Plant.kernels` so that numba compiles or loads
only the kernels of the plant a command uses.

Public API
----------
:class:`Plant` implements the same checked methods for every robot on single samples (numpy arrays
of shape (2,) or (2, 2), SI units); a subclass provides its parameters class and kernels.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit
from ilcforce.compiled.views import address_to_pointer, carray
from ilcforce.plants.kernel_types import __getattr__ as _kernel_types_getattr
from ilcforce.plants.kernel_types import kernel_signature, kernel_type

__all__ = ["UnreachableError", "PlantKernels", "Plant", "params_view", "kernel_signature", "kernel_type", "check_pair",
           "task_space", "task_from_dynamics"]

def __getattr__(name: str):
    """``KIN_SIGNATURE`` ... and ``KIN_TYPE`` ... (:mod:`ilcforce.plants.kernel_types`)."""
    return _kernel_types_getattr(name)


@njit(cache=True, error_model="numpy")
def params_view(address, n):
    """The packed parameter vector of length n at ``address``, as a read-only-by-convention array."""
    return carray(address_to_pointer(address), n)


@njit(cache=True, error_model="numpy")
def task_space(J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11):
    """The task-space inertia and Coriolis matrices of eq. (4) from the joint-space model, for every 2-DOF
    plant: D = J^-T Dq J^-1 and C = J^-T (Cq - Dq J^-1 dJ) J^-1. Returns (D00, D01, D11, C00, C01, C10,
    C11, Ji00, Ji01, Ji10, Ji11), Ji = J^-1 (G = J^-T G_q needs it)."""
    det = J00 * J11 - J01 * J10
    Ji00, Ji01, Ji10, Ji11 = J11 / det, -J01 / det, -J10 / det, J00 / det  # J^-1
    # D = Ji^T Dq Ji                                                                  eq. (4)
    T00 = Dq00 * Ji00 + Dq01 * Ji10
    T01 = Dq00 * Ji01 + Dq01 * Ji11
    T10 = Dq01 * Ji00 + Dq11 * Ji10
    T11 = Dq01 * Ji01 + Dq11 * Ji11
    D00 = Ji00 * T00 + Ji10 * T10
    D01 = Ji00 * T01 + Ji10 * T11
    D11 = Ji01 * T01 + Ji11 * T11
    # C = Ji^T (Cq - Dq Ji dJ) Ji                                                     eq. (4)
    K00 = dJ00 * Ji00 + dJ01 * Ji10  # dJ Ji
    K01 = dJ00 * Ji01 + dJ01 * Ji11
    K10 = dJ10 * Ji00 + dJ11 * Ji10
    K11 = dJ10 * Ji01 + dJ11 * Ji11
    Q00 = Cq00 * Ji00 + Cq01 * Ji10 - (T00 * K00 + T01 * K10)  # Cq Ji - Dq Ji dJ Ji
    Q01 = Cq00 * Ji01 + Cq01 * Ji11 - (T00 * K01 + T01 * K11)
    Q10 = Cq10 * Ji00 + Cq11 * Ji10 - (T10 * K00 + T11 * K10)
    Q11 = Cq10 * Ji01 + Cq11 * Ji11 - (T10 * K01 + T11 * K11)
    C00 = Ji00 * Q00 + Ji10 * Q10
    C01 = Ji00 * Q01 + Ji10 * Q11
    C10 = Ji01 * Q00 + Ji11 * Q10
    C11 = Ji01 * Q01 + Ji11 * Q11
    return D00, D01, D11, C00, C01, C10, C11, Ji00, Ji01, Ji10, Ji11


@njit(cache=True, error_model="numpy")
def task_from_dynamics(dyn, d1, d2):
    """The TASK tuple (ok, Px, Py, vx, vy, J, D, C, G) of eq. (4) from a plant's DYN tuple at joint rates
    (d1, d2): what a plant with gravity returns from its task kernel."""
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, G1, G2) = dyn
    (D00, D01, D11, C00, C01, C10, C11, Ji00, Ji01, Ji10, Ji11) = task_space(
        J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11, Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11)  # eq. (4)
    # G = Ji^T G_q                                                                    eq. (4)
    Gx = Ji00 * G1 + Ji10 * G2
    Gy = Ji01 * G1 + Ji11 * G2
    return (ok, px, py, J00 * d1 + J01 * d2, J10 * d1 + J11 * d2, J00, J01, J10, J11,
            D00, D01, D11, C00, C01, C10, C11, Gx, Gy)


class UnreachableError(ValueError):
    """A point or pose outside the plant's working mode."""


class PlantKernels(NamedTuple):
    """The compiled kernels of one plant (numba dispatchers with the signatures above)."""

    kin: object
    accel: object
    task: object
    dyn: object
    ik: object


def compile_kernels(kin, accel, task, dyn, ik) -> PlantKernels:
    """A plant's five interface functions compiled with the fixed signatures above (or loaded from
    numba's on-disk cache, which is keyed by each function's own module)."""
    nb = _jit.numba()

    def jit(kind, fn):
        return nb.njit(kernel_signature(kind), cache=True, error_model="numpy")(fn)
    return PlantKernels(kin=jit("KIN", kin), accel=jit("ACCEL", accel), task=jit("TASK", task), dyn=jit("DYN", dyn),
                        ik=jit("IK", ik))


def check_pair(name: str, value) -> tuple[float, float]:
    arr = np.asarray(value, dtype=np.float64)
    if arr.shape != (2,):
        raise ValueError(f"{name} must have shape (2,), got {arr.shape}")
    return float(arr[0]), float(arr[1])


class PackedParams:
    """What every plant's frozen parameter dataclass shares: the packed vector the kernels read
    and scaled copies (the perturbation). Subclasses set ``param_names`` (the packing order)."""

    param_names: tuple[str, ...] = ()

    def as_array(self) -> np.ndarray:
        """Packed float64 vector in ``param_names`` order, for the compiled kernels."""
        return np.array([getattr(self, name) for name in self.param_names], dtype=np.float64)

    def scaled(self, name: str, factor: float):
        """A copy with parameter ``name`` multiplied by ``factor`` (e.g. m3 x 1.4)."""
        if name not in self.param_names:
            raise ValueError(f"unknown plant parameter {name!r}; expected one of {', '.join(self.param_names)}")
        return replace(self, **{name: getattr(self, name) * factor})


class Plant:
    """A 2-DOF manipulator behind the common interface. Subclasses set ``params_class``,
    ``working_mode`` (words for error messages) and implement :meth:`kernels`."""

    params_class: type = object
    working_mode = "the working mode"
    #: True if the plant's gravity vector G_q can be non-zero (C3 then learns Theta's G block)
    has_gravity = False
    #: joints = task axes (docs/model.md#n-dof): a 2-DOF plant runs the 2-D loop
    dimension = 2

    def __init__(self, params=None):
        self.params = params if params is not None else self.params_class()
        self._p = self.params.as_array()
        self._address = self._p.ctypes.data  # what the kernels take; self._p keeps it alive

    @staticmethod
    def kernels() -> PlantKernels:
        """The numba dispatchers of the five kernels (what numba-compiled code takes)."""
        raise NotImplementedError

    #: the n-joint interface (ilcforce.plants.nd): joints, task dimensions, scratch floats of nd_dyn
    nd_joints = 2
    nd_task = 2
    nd_scratch = 0

    @staticmethod
    def nd_kernel():
        """The numba dispatcher of the plant's ``nd_dyn`` (``ilcforce.plants.nd``): its DYN kernel's
        entries at the n-joint interface's offsets (n = 2), compiled or loaded on first call."""
        raise NotImplementedError

    @property
    def nd_width(self) -> int:
        """The length of the ``out`` array :meth:`nd_kernel` writes (``ilcforce.plants.nd.nd_width``)."""
        from ilcforce.plants.nd import nd_width

        return nd_width(self)

    def check_frame(self, frame: np.ndarray) -> None:
        """Raise ValueError unless the wall's task frame ``frame`` (``Wall.frame``) is one this plant works in: a
        planar plant's closed forms (its tau_d) take the world's axes, the wall normal to y (``frame`` is I)."""
        if not np.allclose(frame, np.eye(2), rtol=0.0, atol=1e-12):  # a tilt of round-off size is no tilt
            raise ValueError("a planar robot's wall is normal to y: leave wall.normal and wall.tangent out, or give "
                             f"(0, 1) and (1, 0); they make the frame {np.asarray(frame).round(6).tolist()}")

    def desired_inputs(self, frame, wall_sign: float, reference_log: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """tau_d and J^-T tau_d along the reference on the log grid (``ilcforce.simulate.desired_inputs``):
        the compiled kernel of :mod:`ilcforce.plants.desired` (ahead-of-time, or numba's: the same code, the
        same numbers). A planar plant's task frame is the world's (``frame`` is I: :meth:`check_frame`)."""
        from ilcforce.compiled import aot

        self.check_frame(frame)
        ref = reference_log
        tau_d = np.empty((ref.shape[0], 2))
        task_d = np.empty((ref.shape[0], 2))
        compiled = aot.desired(type(self))
        if compiled is not None:
            bad = compiled(self.address, ref, wall_sign, tau_d, task_d)
        else:
            from ilcforce.plants import desired  # numba's, loaded on first use only

            kernels = self.kernels()
            bad = desired.desired_kernel(kernels.dyn, kernels.ik, self.address, ref, wall_sign, tau_d, task_d)
        if bad >= 0:
            raise UnreachableError(f"the desired pose ({ref[bad, 0]:.6g}, {ref[bad, 1]:.6g}) m is not reachable "
                                   f"in {self.working_mode}")
        return tau_d, task_d

    def calls(self) -> PlantKernels:
        """The five kernels as Python calls them: the ahead-of-time compiled ones when built
        (numba is then not imported), else :meth:`kernels`."""
        return _jit.python_calls(type(self), self.kernels, PlantKernels)

    @property
    def packed(self) -> np.ndarray:
        """The packed parameter vector."""
        return self._p

    @property
    def address(self) -> int:
        """The address of :attr:`packed`, the ``p`` argument of the kernels (valid while self lives)."""
        return self._address

    def _outside(self, th1, th2):
        return UnreachableError(f"joint angles ({th1:.6g}, {th2:.6g}) rad are outside {self.working_mode}")

    def _kin(self, theta):
        th1, th2 = check_pair("theta", theta)
        out = self.calls().kin(self._address, th1, th2)
        if not out[0]:
            raise self._outside(th1, th2)
        return out

    def _dyn(self, theta, dtheta):
        th1, th2 = check_pair("theta", theta)
        d1, d2 = check_pair("dtheta", dtheta)
        out = self.calls().dyn(self._address, th1, th2, d1, d2)
        if not out[0]:
            raise self._outside(th1, th2)
        return out

    def _task(self, theta, dtheta):
        th1, th2 = check_pair("theta", theta)
        d1, d2 = check_pair("dtheta", dtheta)
        out = self.calls().task(self._address, th1, th2, d1, d2)
        if not out[0]:
            raise self._outside(th1, th2)
        return out

    # --- kinematics ----------------------------------------------------------------------
    def forward_kinematics(self, theta) -> np.ndarray:
        """End-effector position P (m), shape (2,), of joint angles theta (rad)."""
        out = self._kin(theta)
        return np.array([out[1], out[2]])

    def inverse_kinematics(self, position) -> np.ndarray:
        """Joint angles (rad) in the working mode for end-effector position P (m); raises if unreachable."""
        px, py = check_pair("position", position)
        k = self.calls()
        ok, th1, th2 = k.ik(self._address, px, py)
        fk = k.kin(self._address, th1, th2) if ok else (0.0,)
        # the angles must map back to P in the working mode (e.g. the five-bar's lower assembly
        # has elbows-out angles whose forward kinematics is another point)
        if not fk[0] or math.hypot(fk[1] - px, fk[2] - py) > 1e-9:
            raise UnreachableError(f"point ({px:.6g}, {py:.6g}) m is not reachable in {self.working_mode}")
        return np.array([th1, th2])

    def jacobian(self, theta) -> np.ndarray:
        """J with dP/dt = J dtheta, shape (2, 2), m/rad."""
        out = self._kin(theta)
        return np.array([[out[3], out[4]], [out[5], out[6]]])

    def jacobian_derivative(self, theta, dtheta) -> np.ndarray:
        """dJ/dt along dtheta, shape (2, 2)."""
        out = self._dyn(theta, dtheta)
        return np.array([[out[7], out[8]], [out[9], out[10]]])

    # --- joint-space model (eq. 1) -------------------------------------------------------
    def joint_inertia(self, theta) -> np.ndarray:
        """Dq(theta), shape (2, 2), kg m^2."""
        out = self._dyn(theta, (0.0, 0.0))
        return np.array([[out[11], out[12]], [out[12], out[13]]])

    def joint_coriolis(self, theta, dtheta) -> np.ndarray:
        """Cq(theta, dtheta), shape (2, 2), kg m^2 / s; dDq/dt - 2 Cq is skew-symmetric."""
        out = self._dyn(theta, dtheta)
        return np.array([[out[14], out[15]], [out[16], out[17]]])

    def gravity(self, theta) -> np.ndarray:
        """G_q(theta), shape (2,), N m (zero for a plant moving in a horizontal plane)."""
        out = self._dyn(theta, (0.0, 0.0))
        return np.array([out[18], out[19]])

    # --- task-space model (eq. 4) --------------------------------------------------------
    def task_inertia(self, theta) -> np.ndarray:
        """D = J^-T Dq J^-1 (eq. 4), shape (2, 2), kg."""
        out = self._task(theta, (0.0, 0.0))
        return np.array([[out[9], out[10]], [out[10], out[11]]])

    def task_coriolis(self, theta, dtheta) -> np.ndarray:
        """C = -J^-T Dq J^-1 dJ J^-1 + J^-T Cq J^-1 (eq. 4), shape (2, 2), kg / s."""
        out = self._task(theta, dtheta)
        return np.array([[out[12], out[13]], [out[14], out[15]]])

    def task_gravity(self, theta) -> np.ndarray:
        """G = J^-T G_q (eq. 4), shape (2,), N."""
        out = self._task(theta, (0.0, 0.0))
        return np.array([out[16], out[17]])

    def task_gravity_along(self, positions) -> np.ndarray:
        """G = J^-T G_q (N) at each end-effector position of ``positions`` (n, 2) (m), shape (n, 2):
        the task-space gravity C3's G block should learn along a path (zero without gravity)."""
        positions = np.asarray(positions, dtype=np.float64)
        if positions.ndim != 2 or positions.shape[1] != 2:
            raise ValueError(f"positions must have shape (n, 2), got {positions.shape}")
        return np.array([self.task_gravity(self.inverse_kinematics(pos)) for pos in positions]).reshape(-1, 2)

    # --- dynamics ------------------------------------------------------------------------
    def inverse_dynamics(self, theta, dtheta, ddtheta, force_on_end_effector=(0.0, 0.0)) -> np.ndarray:
        """tau = Dq ddtheta + Cq dtheta + G_q - J^T f (N m), f the force on the robot (eq. 1)."""
        out = self._dyn(theta, dtheta)
        Dq = np.array([[out[11], out[12]], [out[12], out[13]]])
        Cq = np.array([[out[14], out[15]], [out[16], out[17]]])
        J = np.array([[out[3], out[4]], [out[5], out[6]]])
        f = np.asarray(force_on_end_effector, dtype=np.float64)
        tau = Dq @ np.asarray(ddtheta, float) + Cq @ np.asarray(dtheta, float) - J.T @ f
        if self.has_gravity:
            tau = tau + np.array([out[18], out[19]])
        return tau

    def forward_dynamics(self, theta, dtheta, tau, force_on_end_effector=(0.0, 0.0)) -> np.ndarray:
        """ddtheta (rad/s^2) from Dq ddtheta + Cq dtheta + G_q = tau + J^T f, f the force on the robot."""
        th1, th2 = check_pair("theta", theta)
        d1, d2 = check_pair("dtheta", dtheta)
        t1, t2 = check_pair("tau", tau)
        fx, fy = check_pair("force_on_end_effector", force_on_end_effector)
        self._kin(theta)
        out = self.calls().accel(self._address, th1, th2, d1, d2)
        r1 = t1 + out[3] * fx + out[5] * fy - out[9]
        r2 = t2 + out[4] * fx + out[6] * fy - out[10]
        return np.array([out[11] * r1 + out[12] * r2, out[12] * r1 + out[13] * r2])

    def kinetic_energy(self, theta, dtheta) -> float:
        """T = dtheta^T Dq dtheta / 2 (J)."""
        d = np.asarray(dtheta, dtype=np.float64)
        return 0.5 * float(d @ self.joint_inertia(theta) @ d)

    def potential_energy(self, theta) -> float:
        """V(theta) with G_q = dV/dtheta (J); 0 for a plant without gravity."""
        return 0.0
