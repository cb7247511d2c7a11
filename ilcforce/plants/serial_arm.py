"""The plant of an n-joint serial arm described by a packed parameter vector (``ilcforce.plants.chain``;
``ilcforce.plants.model_file`` builds one from a URDF or MJCF file): the public methods of the
closed-form plants (``ilcforce.plants.base.Plant``) in n dimensions, plus the joint-torque regressor.

Joint values q (rad for a hinge, m for a slide) are the model file's; the task is the end
effector's world position P (3,), J its linear-velocity Jacobian (3, n). The task-space model of
eq. (4) needs a square J, so ``task_*`` require n = 3 (docs/model.md#model-file).
"""

from __future__ import annotations

import numpy as np

from ilcforce.plants import chain
from ilcforce.plants.base import UnreachableError

__all__ = ["SerialArm"]

#: the end effector's position: the task dimension of a spatial arm
TASK_DIMENSION = 3
#: inverse kinematics: the position error it must reach (m), and its most Newton steps
IK_TOLERANCE = 1e-12
IK_STEPS = 100
#: a Jacobian whose smallest singular value is below this fraction of its largest is singular
SINGULAR = 1e-9


class SerialArm:
    """An n-joint serial arm of hinge and slide joints with gravity (docs/model.md#model-file)."""

    def __init__(self, packed, *, joint_names=(), link_names=(), end_effector: str = "", source: str = "") -> None:
        self._p = np.ascontiguousarray(packed, dtype=np.float64)
        self._p.setflags(write=False)
        self.n = chain.link_count(self._p)
        self.joint_names = tuple(joint_names)
        self.link_names = tuple(link_names)
        self.end_effector = end_effector
        self.source = source

    def __repr__(self) -> str:
        return (f"SerialArm({self.n} joints {', '.join(self.joint_names)}; end effector {self.end_effector!r}; "
                f"from {self.source or 'a packed vector'})")

    @property
    def packed(self) -> np.ndarray:
        """The packed parameter vector the kernels read (read-only)."""
        return self._p

    @property
    def address(self) -> int:
        """The address of :attr:`packed`, the ``p`` argument of :meth:`nd_kernel` (valid while self lives:
        the arm holds the vector)."""
        return self._p.ctypes.data

    # --- the n-joint interface (ilcforce.plants.nd) -----------------------------------------------
    @property
    def nd_joints(self) -> int:
        return self.n

    nd_task = TASK_DIMENSION

    @property
    def nd_scratch(self) -> int:
        """The scratch floats the chain kernel uses after the interface's entries."""
        from ilcforce.plants import chain_nd

        return chain_nd.scratch(self.n)

    @property
    def nd_width(self) -> int:
        """The length of the ``out`` array :meth:`nd_kernel` writes."""
        from ilcforce.plants.nd import nd_width

        return nd_width(self)

    def nd_kernel(self):
        """The numba dispatcher of the chain's allocation-free ``nd_dyn`` (``ilcforce.plants.chain_nd``),
        the same for every chain: it reads the arm's vector at :attr:`address`. The interface needs as
        many joints as task dimensions (3)."""
        self._square_task()
        from ilcforce.plants import chain_nd

        return chain_nd.kernel()

    def _square_task(self) -> None:
        if self.n != TASK_DIMENSION:
            raise ValueError(f"the task-space model needs as many joints as task dimensions ({TASK_DIMENSION}); "
                             f"this arm has {self.n}")

    @property
    def gravity_vector(self) -> np.ndarray:
        """Gravity in the world frame (m/s^2), shape (3,)."""
        return np.array(self._p[5:8])

    def _joints(self, name: str, value) -> np.ndarray:
        arr = np.ascontiguousarray(value, dtype=np.float64)
        if arr.shape != (self.n,):
            raise ValueError(f"{name} must have shape ({self.n},), got {arr.shape}")
        return arr

    def _zeros(self) -> np.ndarray:
        return np.zeros(self.n)

    # --- kinematics ----------------------------------------------------------------------------
    def forward_kinematics(self, theta) -> np.ndarray:
        """End-effector position P (m) in the world frame, shape (3,)."""
        return chain.forward_kinematics(self._p, self._joints("theta", theta))

    def inverse_kinematics(self, position, guess) -> np.ndarray:
        """Joint values q (shape (n,)) with forward_kinematics(q) = ``position`` (m, shape (3,)) to
        :data:`IK_TOLERANCE`, by damped Newton steps from ``guess`` (shape (n,)): the least-squares step
        J^+ (P* - P(q)), halved until it reduces the error. Raises UnreachableError (one line) when it
        does not converge, or when J is singular at the answer."""
        target = np.asarray(position, dtype=np.float64)
        if target.shape != (TASK_DIMENSION,):
            raise ValueError(f"position must have shape ({TASK_DIMENSION},), got {target.shape}")
        if not np.all(np.isfinite(target)):
            raise ValueError(f"position must be finite, got {target}")
        q = self._joints("guess", guess).copy()
        error = target - chain.forward_kinematics(self._p, q)
        where = f"point ({', '.join(f'{x:.6g}' for x in target)}) m"
        for _ in range(IK_STEPS):
            if np.linalg.norm(error) <= IK_TOLERANCE:
                break
            step = np.linalg.lstsq(chain.jacobian(self._p, q), error, rcond=None)[0]
            for _halving in range(30):
                trial = q + step
                trial_error = target - chain.forward_kinematics(self._p, trial)
                if np.linalg.norm(trial_error) < np.linalg.norm(error):
                    break
                step = 0.5 * step
            else:  # no step along J^+ e reduces the error: a local minimum away from the point
                break
            q, error = trial, trial_error
        distance = float(np.linalg.norm(error))
        if distance > IK_TOLERANCE:
            raise UnreachableError(f"{where} is not reachable from guess {_vec(guess)}: inverse kinematics stopped "
                                   f"{distance:.3g} m away")
        sv = np.linalg.svd(chain.jacobian(self._p, q), compute_uv=False)
        if sv[-1] <= SINGULAR * sv[0]:
            raise UnreachableError(f"{where} is reached at a singular pose q = {_vec(q)} (Jacobian's singular values "
                                   f"{_vec(sv)})")
        return q

    def jacobian(self, theta) -> np.ndarray:
        """J with dP/dt = J dtheta, shape (3, n)."""
        return chain.jacobian(self._p, self._joints("theta", theta))

    def jacobian_derivative(self, theta, dtheta) -> np.ndarray:
        """dJ/dt along dtheta, shape (3, n)."""
        return chain.jacobian_derivative(self._p, self._joints("theta", theta), self._joints("dtheta", dtheta))

    def jacobian_derivative_times_rate(self, theta, dtheta) -> np.ndarray:
        """dJ/dt dtheta (m/s^2), shape (3,): the end effector's acceleration at ddtheta = 0."""
        d = self._joints("dtheta", dtheta)
        return self.jacobian_derivative(theta, d) @ d

    # --- joint-space model (eq. 1) -------------------------------------------------------------
    def joint_inertia(self, theta) -> np.ndarray:
        """M(theta) (Dq), shape (n, n), by the composite-rigid-body algorithm."""
        return chain.joint_inertia(self._p, self._joints("theta", theta))

    def joint_coriolis(self, theta, dtheta) -> np.ndarray:
        """Cq(theta, dtheta), shape (n, n), in Christoffel form: dDq/dt - 2 Cq is skew-symmetric."""
        return chain.joint_coriolis(self._p, self._joints("theta", theta), self._joints("dtheta", dtheta))

    def gravity(self, theta) -> np.ndarray:
        """G_q(theta) = dV/dtheta, shape (n,)."""
        z = self._zeros()
        return chain.inverse_dynamics(self._p, self._joints("theta", theta), z, z, True)

    def bias(self, theta, dtheta) -> np.ndarray:
        """Cq(theta, dtheta) dtheta + G_q(theta), shape (n,), by recursive Newton-Euler at ddtheta = 0."""
        return chain.inverse_dynamics(self._p, self._joints("theta", theta), self._joints("dtheta", dtheta),
                                      self._zeros(), True)

    # --- task-space model (eq. 4, n = 3) -------------------------------------------------------
    def _square(self, theta):
        self._square_task()
        J = self.jacobian(theta)
        return J, np.linalg.inv(J)

    def task_inertia(self, theta) -> np.ndarray:
        """D = J^-T Dq J^-1 (eq. 4), shape (3, 3), kg."""
        J, Ji = self._square(theta)
        return Ji.T @ self.joint_inertia(theta) @ Ji

    def task_coriolis(self, theta, dtheta) -> np.ndarray:
        """C = J^-T (Cq - Dq J^-1 dJ) J^-1 (eq. 4), shape (3, 3), kg / s."""
        J, Ji = self._square(theta)
        Dq = self.joint_inertia(theta)
        return Ji.T @ (self.joint_coriolis(theta, dtheta) - Dq @ Ji @ self.jacobian_derivative(theta, dtheta)) @ Ji

    def task_gravity(self, theta) -> np.ndarray:
        """G = J^-T G_q (eq. 4), shape (3,), N."""
        J, _ = self._square(theta)
        return np.linalg.solve(J.T, self.gravity(theta))

    # --- dynamics ------------------------------------------------------------------------------
    def inverse_dynamics(self, theta, dtheta, ddtheta, force_on_end_effector=(0.0, 0.0, 0.0)) -> np.ndarray:
        """tau = Dq ddtheta + Cq dtheta + G_q - J^T f (N m or N), f the force on the robot (eq. 1),
        by recursive Newton-Euler."""
        q = self._joints("theta", theta)
        tau = chain.inverse_dynamics(self._p, q, self._joints("dtheta", dtheta), self._joints("ddtheta", ddtheta), True)
        f = np.asarray(force_on_end_effector, dtype=np.float64)
        if f.shape != (3,):
            raise ValueError(f"force_on_end_effector must have shape (3,), got {f.shape}")
        return tau - self.jacobian(q).T @ f if f.any() else tau

    def forward_dynamics(self, theta, dtheta, tau, force_on_end_effector=(0.0, 0.0, 0.0)) -> np.ndarray:
        """ddtheta from Dq ddtheta + Cq dtheta + G_q = tau + J^T f, f the force on the robot."""
        q = self._joints("theta", theta)
        f = np.asarray(force_on_end_effector, dtype=np.float64)
        if f.shape != (3,):
            raise ValueError(f"force_on_end_effector must have shape (3,), got {f.shape}")
        rhs = self._joints("tau", tau) + self.jacobian(q).T @ f - self.bias(q, dtheta)
        return np.linalg.solve(self.joint_inertia(q), rhs)

    def kinetic_energy(self, theta, dtheta) -> float:
        """T = dtheta^T Dq dtheta / 2 (J)."""
        d = self._joints("dtheta", dtheta)
        return 0.5 * float(d @ self.joint_inertia(theta) @ d)

    def potential_energy(self, theta) -> float:
        """V = -sum_i m_i g . c_i (J), zero with every centre of mass at the world origin; G_q = dV/dtheta."""
        return float(chain.potential_energy(self._p, self._joints("theta", theta)))

    # --- linear parametrisation ----------------------------------------------------------------
    def regressor(self, theta, dtheta, ddtheta) -> np.ndarray:
        """Y (n, 10 n) with Y a = inverse_dynamics(theta, dtheta, ddtheta), a = inertial_parameters().ravel()
        (gravity included): inverse dynamics is linear in each link's ten inertial parameters."""
        return chain.regressor(self._p, self._joints("theta", theta), self._joints("dtheta", dtheta),
                               self._joints("ddtheta", ddtheta))

    def inertial_parameters(self) -> np.ndarray:
        """Per link [m, m cx, m cy, m cz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz], shape (n, 10): mass (kg), first
        moment (kg m) and inertia about the link frame's origin (kg m^2), in the link frame."""
        return chain.inertial_parameters(self._p)


def _vec(values) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in np.ravel(values)) + ")"
