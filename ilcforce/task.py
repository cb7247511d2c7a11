"""The contact task: the compliant wall and the reference (docs/model.md#wall, docs/model.md#task; paper Section 4.1).

Force convention (erratum 1). With the default ``force_sign = "applied"`` the robot works on the side
y <= y_e and F is the force the end-effector applies to the wall, F = (0, K_e max(0, y - y_e)) >= 0;
the wall pushes back on the robot with -F, and the control laws add +F as feed-forward.
``force_sign = "paper"`` is the literal reading of eqs. (9), (11), (14): the robot sits on the far
side (y >= y_e), F is the force on the robot, F = (0, K_e max(0, y_e - y)), and the laws subtract it.
Both are encoded by one sign w (+1 applied, -1 paper): penetration w (y - y_e), force on the robot
(0, -w F_y), feed-forward w F, and the pose that produces F_d is y_e + w F_d / K_e.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ilcforce.compiled.jit import njit  # numba's, imported only when a kernel runs through numba (ilcforce/compiled/jit.py)
from ilcforce.records import TASK_DIMENSIONS  # a position in the plane or in space

FORCE_SIGNS = {"applied": 1.0, "paper": -1.0}

#: Columns of the per-sample reference array made by :meth:`Reference.sample`.
REF_POSITION = 0  # P_d (x, y), m
REF_VELOCITY = 2  # dP_d/dt, m/s
REF_ACCELERATION = 4  # d2P_d/dt2, m/s^2
REF_FORCE = 6  # F_d (x, y), N
REF_FORCE_RATE = 8  # dF_d/dt, N/s
REF_FORCE_ACCEL = 10  # d2F_d/dt2, N/s^2


def _axis(k: int, n: int) -> tuple[float, ...]:
    """The unit vector along the world's axis k in n dimensions."""
    return tuple(1.0 if i == k else 0.0 for i in range(n))


def reference_block(ref: np.ndarray, column_2d: int, n: int) -> np.ndarray:
    """The n columns of one quantity (``column_2d``: its REF_* constant, the planar layout's first column) of a
    reference sampled for a task of n axes, whose blocks are n wide in the same order (shape (rows, n))."""
    start = column_2d // 2 * n
    return ref[:, start:start + n]


#: The packed wall (:meth:`Wall.packed`), what the compiled loop reads: y_e, K_e, w at these offsets, the task
#: frame's R (n x n, row-major) from WALL_FRAME, then, after R (at WALL_FRAME + n n + these), D_e, mu, v_eps.
WALL_POSITION, WALL_STIFFNESS, WALL_SIGN, WALL_FRAME = 0, 1, 2, 3
AFTER_FRAME_DAMPING, AFTER_FRAME_FRICTION, AFTER_FRAME_FRICTION_VELOCITY = 0, 1, 2


@njit(cache=True, error_model="numpy")
def wall_force(y, vy, ye, ke, de, w):
    """The wall's normal contact law, its one definition (docs/model.md#wall): the force F_y (N) the end-effector
    applies at height y (m) moving at vy (m/s), a unilateral Kelvin-Voigt wall of stiffness K_e (N/m) and damping
    D_e (N s/m): with the penetration pen = w (y - y_e), F_y = max(0, K_e pen + D_e dpen/dt) while pen > 0, else 0
    (the robot feels -w F_y). The clamp at 0 keeps the wall from pulling: leaving the wall fast, the damper's
    term would exceed the spring's and pull the robot back, which a surface it only touches cannot do. With
    D_e = 0 this is the spring K_e max(0, pen), computed as before the damper existed, to the last bit."""
    pen = w * (y - ye)
    if pen <= 0.0:
        return 0.0
    f = ke * pen
    if de != 0.0:
        f += de * w * vy
    return f if f > 0.0 else 0.0


@njit(cache=True, error_model="numpy")
def friction_scale(speed, v_eps):
    """tanh(speed / v_eps) / speed (1/(m/s)): the in-plane velocity v (speed |v|, m/s) times this is the smoothed unit
    vector of v, so the friction on the robot is -mu F_n scale v (docs/model.md#wall). Its length tanh(|v| / v_eps)
    is 1 to within 1e-4 above 5 v_eps and goes smoothly to 0 at rest (the slope 1 / v_eps there): a smooth sign,
    since RK4 on a right-hand side with a jump (Coulomb's sign at v = 0) chatters across it and loses its order.
    0 at rest."""
    if speed <= 0.0:
        return 0.0
    return math.tanh(speed / v_eps) / speed


@njit(cache=True, error_model="numpy")
def wall_stiffness(y, vy, ye, ke, w):
    """dF_y/dy of the wall's spring along the motion (the stiffness relation of docs/model.md#acceleration): w K_e in
    contact, 0 out of it; exactly on the surface, the one-sided derivative in the direction of the
    velocity vy (w K_e when entering the wall, 0 when leaving or at rest). The spring's alone, also on a damped
    wall: the estimates take dF = K_e dy and ddF = K_e ddy, what a controller's model of a spring wall gives
    (the damper's D_e ddy and D_e dddy are left to the measured force; docs/model.md#wall says why)."""
    pen = w * (y - ye)
    return w * ke if pen > 0.0 or (pen == 0.0 and w * vy > 0.0) else 0.0


@dataclass(frozen=True)
class Wall:
    """A compliant wall, a unilateral spring and damper along its normal with Coulomb friction in its plane
    (docs/model.md#wall; frictionless and undamped by default): normal to y for a planar robot; for a spatial one
    (docs/model.md#wall-plane) the plane n . P = y_e with unit normal ``normal``, its first in-plane axis along
    ``tangent`` (projected onto the plane), the second n x t."""

    position: float = 0.4  # y_e, the wall's surface along its normal, m
    stiffness: float = 1000.0  # K_e, N/m
    damping: float = 0.0  # D_e, the normal damper (Kelvin-Voigt, the force clamped at 0: it never pulls), N s/m
    friction: float = 0.0  # mu, Coulomb's coefficient: the in-plane force is mu times the normal force, 1
    friction_velocity: float = 0.01  # v_eps, the in-plane speed below which friction's sign is smoothed (tanh), m/s
    force_sign: str = "applied"  # "applied" (the default, docs/model.md#wall) or "paper" (literal signs of eqs. 9-14)
    normal: tuple[float, ...] = ()  # a spatial robot's wall normal in the world frame (3 numbers); () for a planar one
    tangent: tuple[float, ...] = ()  # the direction of the task frame's first in-plane axis (3 numbers)

    def __post_init__(self) -> None:
        if self.force_sign not in FORCE_SIGNS:
            raise ValueError(f"wall.force_sign must be one of {', '.join(FORCE_SIGNS)}, got {self.force_sign!r}")
        if not (math.isfinite(self.stiffness) and self.stiffness > 0):
            raise ValueError(f"wall.stiffness must be finite and positive, got {self.stiffness!r}")
        if not math.isfinite(self.position):
            raise ValueError(f"wall.position must be finite, got {self.position!r}")
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise ValueError(f"wall.damping must be finite and >= 0 (N s/m), got {self.damping!r}")
        if not (math.isfinite(self.friction) and self.friction >= 0):
            raise ValueError(f"wall.friction must be finite and >= 0 (a Coulomb coefficient), got {self.friction!r}")
        if not (math.isfinite(self.friction_velocity) and self.friction_velocity > 0):
            raise ValueError(f"wall.friction_velocity must be finite and positive (m/s), "
                             f"got {self.friction_velocity!r}")
        if self.normal and self.tangent and len(self.normal) != len(self.tangent):
            raise ValueError(f"wall.normal and wall.tangent must have as many numbers each (the task's axes), got "
                             f"{list(self.normal)}, {list(self.tangent)}")
        if self.normal or self.tangent:
            given = len(self.normal or self.tangent)
            if given not in TASK_DIMENSIONS:
                raise ValueError(f"wall.normal and wall.tangent take {' or '.join(map(str, TASK_DIMENSIONS))} numbers (a "
                                 f"task in the plane or in space), got {list(self.normal)}, {list(self.tangent)}")
            self.frame(given)

    def frame(self, n: int) -> np.ndarray:
        """R (n x n): the task frame's axes as rows, X = R P (docs/model.md#wall-plane), for a task of n = 2 or 3
        axes. The rows are t1 = ``tangent`` projected onto the plane, then (in space) t2 = normal x t1, and last
        the unit ``normal``, so that the force axis is the last and the frame is right-handed. Left empty, the
        normal is the y axis and the tangent the x axis, which makes R the identity for a planar robot."""
        if n not in TASK_DIMENSIONS:
            raise ValueError(f"a task has {' or '.join(map(str, TASK_DIMENSIONS))} axes (a position in the plane or in "
                             f"space), not {n}")
        normal = np.asarray(self.normal or _axis(1, n), dtype=np.float64)
        t1 = np.asarray(self.tangent or _axis(0, n), dtype=np.float64)
        if normal.shape != (n,) or t1.shape != (n,):
            raise ValueError(f"wall.normal and wall.tangent must be {n} numbers each for a robot with a task of {n} "
                             f"axes (or left out: the wall normal to y); got {list(self.normal)}, "
                             f"{list(self.tangent)}")
        if not (np.all(np.isfinite(normal)) and np.linalg.norm(normal) > 0):
            raise ValueError(f"wall.normal must be a finite non-zero vector, got {list(self.normal)}")
        normal = normal / np.linalg.norm(normal)
        given = t1
        t1 = t1 - (t1 @ normal) * normal
        if not (np.all(np.isfinite(t1)) and np.linalg.norm(t1) > 1e-9 * np.linalg.norm(given)):
            raise ValueError(f"wall.tangent ({list(self.tangent) if self.tangent else 'left out: the x axis'}) must "
                             f"be non-zero and not parallel to wall.normal "
                             f"({list(self.normal) if self.normal else 'left out: the y axis'})")
        rows = [t1 / np.linalg.norm(t1)]
        for _ in range(n - 2):  # the in-plane axes after t1: in space the one axis t2 = normal x t1
            rows.append(np.cross(normal, rows[-1]))
        return np.array([*rows, normal])

    @property
    def sign(self) -> float:
        """w: +1 for the applied-force convention, -1 for the paper's literal reading."""
        return FORCE_SIGNS[self.force_sign]

    def contact_force(self, y: np.ndarray, vy: np.ndarray | float = 0.0) -> np.ndarray:
        """Measured-convention normal contact force F_y (N) for end-effector heights y (m) moving at vy (m/s, along
        the normal; it matters only on a damped wall); any shape (vy broadcast to y's)."""
        y = np.asarray(y, dtype=np.float64)
        vy = np.broadcast_to(np.asarray(vy, dtype=np.float64), y.shape)
        out = np.array([wall_force(p, v, self.position, self.stiffness, self.damping, self.sign)
                        for p, v in zip(y.ravel(), vy.ravel())])
        return out.reshape(y.shape)

    def packed(self, n: int) -> np.ndarray:
        """The wall as the compiled loop reads it (layout: WALL_* above), for a task of n axes: y_e, K_e, w, the
        frame R (n x n, row-major), D_e, mu, v_eps; shape (3 + n n + 3,), contiguous float64."""
        return np.ascontiguousarray(np.concatenate([[self.position, self.stiffness, self.sign], self.frame(n).ravel(),
                                                    [self.damping, self.friction, self.friction_velocity]]),
                                    dtype=np.float64)

    def pose_for_force(self, force: np.ndarray) -> np.ndarray:
        """The height y (m) at which the wall's force equals ``force`` (N) >= 0."""
        return self.position + self.sign * np.asarray(force, dtype=np.float64) / self.stiffness


@dataclass(frozen=True)
class Reference:
    """The task of Section 4.1: x_d = a cos(2 pi f t) + c, F_yd = A sin(2 pi g t) + B (e^t - 1).

    Defaults give x_d = 0.15 cos(pi t / 2) + 0.2 m and F_yd = 5 sin(pi t) + 5 (e^t - 1) N on [0, 2] s.
    """

    duration: float = 2.0  # T, length of one iteration, s
    x_amplitude: float = 0.15  # m
    x_offset: float = 0.2  # m
    x_frequency: float = 0.25  # Hz (pi/2 rad/s)
    force_sine_amplitude: float = 5.0  # N
    force_sine_frequency: float = 0.5  # Hz (pi rad/s)
    force_exp_amplitude: float = 5.0  # N
    # a spatial robot's second in-plane axis (docs/model.md#wall-plane): v_d = v_offset + v_amplitude (1 - cos(2 pi
    # v_frequency t)) / 2, which starts at rest as x_d does and reaches v_offset + v_amplitude
    v_amplitude: float = 0.0  # m
    v_offset: float = 0.0  # m
    v_frequency: float = 0.5  # Hz

    def sample(self, t: np.ndarray, wall: Wall, n: int = 2) -> np.ndarray:
        """Reference and its analytic derivatives at times ``t`` (s), for a task of n axes in the wall's frame.

        Returns a (t.size, 6 n) array of six blocks of n columns: P_d, dP_d, ddP_d, F_d, dF_d, ddF_d (the block
        of a REF_* constant: :func:`reference_block`). In every block the first axis carries x_d's law, the last
        axis (the wall's normal) carries F_d, and a spatial task's middle axis v_d's law
        (docs/model.md#wall-plane). P_d's normal column is the pose that produces F_d on the wall
        (y_e + w F_yd / K_e); the laws use only Sbar P_d, so it serves tau_d and plots.
        """
        if n not in TASK_DIMENSIONS:
            raise ValueError(f"the reference is defined for tasks of {' or '.join(map(str, TASK_DIMENSIONS))} axes, "
                             f"not {n}")
        t = np.asarray(t, dtype=np.float64)
        wx = 2.0 * math.pi * self.x_frequency
        wf = 2.0 * math.pi * self.force_sine_frequency
        wv = 2.0 * math.pi * self.v_frequency
        a, c, av = self.x_amplitude, self.x_offset, self.v_amplitude
        A, B = self.force_sine_amplitude, self.force_exp_amplitude
        et = np.exp(t)
        f = A * np.sin(wf * t) + B * (et - 1.0)
        df = A * wf * np.cos(wf * t) + B * et
        ddf = -A * wf * wf * np.sin(wf * t) + B * et
        w, k = wall.sign, wall.stiffness
        # the three laws, each as (value, rate, acceleration) per block: P_d's blocks, then F_d's
        along = (a * np.cos(wx * t) + c, -a * wx * np.sin(wx * t), -a * wx * wx * np.cos(wx * t))
        across = (self.v_offset + 0.5 * av * (1.0 - np.cos(wv * t)), 0.5 * av * wv * np.sin(wv * t),
                  0.5 * av * wv * wv * np.cos(wv * t))
        normal = (wall.position + w * f / k, w * df / k, w * ddf / k)
        out = np.zeros((t.size, 6 * n))
        for block in range(3):
            out[:, block * n] = along[block]  # the first in-plane axis: x_d
            for axis in range(1, n - 1):  # a spatial task's second in-plane axis: v_d
                out[:, block * n + axis] = across[block]
            out[:, block * n + n - 1] = normal[block]  # the normal: the pose that produces F_d
            out[:, (3 + block) * n + n - 1] = (f, df, ddf)[block]  # F_d along the normal
        return out
