"""What one simulated iteration produces: the record the simulator returns and the store writes.

The record is the boundary between the science (plant, controllers, simulation loop) and the
results machinery (HDF5 store, metrics, reports). Everything in it is plain numpy.

Grids
-----
* control grid: ``t_k = k * Ts`` for ``k = 0 .. n_control - 1`` (``n_control = T / Ts + 1``,
  20001 for the paper's setup). Learned memories live here.
* log grid: every ``log_every``-th control sample (``n_log = (n_control - 1) / log_every + 1``,
  2001 for the paper's setup, i.e. 1 ms). Trajectories live here.

Axis conventions: a task of n axes (n = 2 or 3, :data:`TASK_DIMENSIONS`) has task-space arrays of
shape (n_log, n) with the columns :func:`task_axes` and joint-space arrays (n_log, n) with the columns
:func:`joint_axes`. n = 2, the planar robots: (x, y), x along the wall and y normal to it, and
(joint 1, joint 2) = (theta1, theta2), the two actuated joints. n = 3, a spatial arm pressing on a
plane: the wall's frame (u, v, n), u and v in the plane and n its normal, and joints (1, 2, 3).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

STATUS_COMPLETE = "complete"
STATUS_DIVERGED = "diverged"

#: The task dimensions a record, a store and a metrics row know: n task axes and n joints.
TASK_DIMENSIONS = (2, 3)
_TASK_AXES = {2: ("x", "y"), 3: ("u", "v", "n")}

TASK_AXES = _TASK_AXES[2]
JOINT_AXES = ("1", "2")


def _dimension(n: object) -> int:
    """``n`` checked to be one of :data:`TASK_DIMENSIONS`; ValueError names it otherwise."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or int(n) not in TASK_DIMENSIONS:
        raise ValueError(f"a task has {' or '.join(map(str, TASK_DIMENSIONS))} axes, got {n!r}")
    return int(n)


def task_axes(n: int) -> tuple[str, ...]:
    """The column labels of a task-space array of a task of ``n`` axes: ("x", "y") or ("u", "v", "n")."""
    return _TASK_AXES[_dimension(n)]


def axis_text(axis: str) -> str:
    """A task axis in prose and labels: the paper's X and Y on the planar task; "along u" (v, n) on a plane,
    where a capital N would read as the unit."""
    return axis.upper() if axis in _TASK_AXES[2] else f"along {axis}"


def joint_axes(n: int) -> tuple[str, ...]:
    """The column labels of a joint-space array of a robot of ``n`` joints: ("1", "2") or ("1", "2", "3")."""
    return tuple(str(k) for k in range(1, _dimension(n) + 1))


def _with_axes(table: dict[str, tuple[tuple[str, ...] | None, str, str]], n: int
               ) -> dict[str, tuple[tuple[str, ...] | None, str, str]]:
    """``table`` (a signal table of n = 2) with the axes of a task of ``n`` axes."""
    swap = {TASK_AXES: task_axes(n), JOINT_AXES: joint_axes(n), None: None}
    return {name: (swap[axes], unit, description) for name, (axes, unit, description) in table.items()}


#: Logged signals: name -> (axes, unit, description). ``axes`` is None for a scalar per sample,
#: otherwise the column labels of the trailing dimension. Every array is (n_log,) or (n_log, 2),
#: time-major. After a divergence the remaining samples are NaN. This is the table of a task of 2
#: axes; :func:`log_signals` gives it for n axes.
LOG_SIGNALS: dict[str, tuple[tuple[str, ...] | None, str, str]] = {
    "time": (None, "s", "time of the log sample"),
    "joint_angle": (JOINT_AXES, "rad", "true actuated joint angles theta"),
    "joint_rate": (JOINT_AXES, "rad/s", "true actuated joint rates dtheta"),
    "joint_angle_measured": (JOINT_AXES, "rad", "encoder reading (true + noise)"),
    "joint_rate_measured": (JOINT_AXES, "rad/s", "rate sensor reading (true + noise)"),
    "position": (TASK_AXES, "m", "true end-effector position P"),
    "velocity": (TASK_AXES, "m/s", "true end-effector velocity dP/dt"),
    "contact_force": (TASK_AXES, "N", "true contact force F, the force the end-effector applies (docs/model.md#wall)"),
    "contact_force_measured": (TASK_AXES, "N", "force sensor reading (true + noise)"),
    "disturbance": (TASK_AXES, "N", "task-space disturbance F_v of eq. (1), tau_v = J^T F_v: the robot feels -F_v (docs/model.md#noise)"),
    "torque": (JOINT_AXES, "N m", "applied joint torque tau (zero-order hold)"),
    "task_input": (TASK_AXES, "N", "task-space input F_E = J^-T tau at the true pose"),
    "desired_torque": (JOINT_AXES, "N m", "tau_d: inverse dynamics of this iteration's true plant along the desired motion, with the desired contact force"),
    "desired_task_input": (TASK_AXES, "N", "J^-T tau_d at the desired pose"),
    "sliding_surface": (TASK_AXES, "m/s", "sigma as computed by the controller from its measurements (eq. 8)"),
    "position_error": (TASK_AXES, "m", "e_P = Sbar (P_d - P), true position (eq. 6)"),
    "force_error": (TASK_AXES, "N", "e_F = S (F_d - F), true force (eq. 7)"),
    "implicit_fallbacks": (None, "1", "control samples in the log interval ending at this sample where the "
                           "implicit acceleration scheme had no usable root and fell back "
                           "(simulation.implicit_fallback); 0 for the filtered scheme. After a divergence the "
                           "fallbacks since the last row are counted in the row whose interval holds it, so "
                           "the signal sums to the iteration's fallback_count"),
}

#: Reference signals stored once per file under /reference, on the log grid (a task of 2 axes;
#: :func:`reference_signals` gives them for n axes).
REFERENCE_SIGNALS: dict[str, tuple[tuple[str, ...] | None, str, str]] = {
    "time": (None, "s", "time of the log sample"),
    "position_desired": (TASK_AXES, "m", "P_d; x is position-controlled, y is y_e + F_yd / K_e (the pose that produces F_d)"),
    "velocity_desired": (TASK_AXES, "m/s", "dP_d/dt"),
    "acceleration_desired": (TASK_AXES, "m/s^2", "d2P_d/dt2"),
    "force_desired": (TASK_AXES, "N", "F_d"),
}

#: P_d's description per task dimension: the planar one names its axes
_POSITION_DESIRED = {2: REFERENCE_SIGNALS["position_desired"][2],
                     3: "P_d; the in-plane axes are position-controlled, the normal one is the pose that produces F_d"}


def log_signals(n: int) -> dict[str, tuple[tuple[str, ...] | None, str, str]]:
    """The logged signals of a task of ``n`` axes: :data:`LOG_SIGNALS` with (n_log, n) arrays whose
    columns are :func:`task_axes` or :func:`joint_axes` of ``n``; exactly :data:`LOG_SIGNALS` for 2."""
    return _with_axes(LOG_SIGNALS, _dimension(n))


def reference_signals(n: int) -> dict[str, tuple[tuple[str, ...] | None, str, str]]:
    """The reference signals of a task of ``n`` axes, (n_log, n) each but ``time``; exactly
    :data:`REFERENCE_SIGNALS` for 2 (whose P_d description names x and y)."""
    table = _with_axes(REFERENCE_SIGNALS, _dimension(n))
    axes, unit, _description = table["position_desired"]
    table["position_desired"] = (axes, unit, _POSITION_DESIRED[n])
    return table


def signals_dimension(signals, name: str, where: str) -> int:
    """The task dimension n of a set of signals: the width of ``signals[name]`` (n_log, n), checked to be
    one of :data:`TASK_DIMENSIONS`. ValueError (one line, naming ``where``) when it is missing or of another
    shape."""
    if name not in signals:
        raise ValueError(f"{where} is missing signal {name!r}")
    shape = np.shape(signals[name])
    if len(shape) != 2 or shape[1] not in TASK_DIMENSIONS:
        raise ValueError(f"{where}[{name!r}] has shape {shape}, expected (n_log, n) with n task axes, n in "
                         f"{TASK_DIMENSIONS}")
    return int(shape[1])


def record_dimension(log: dict[str, np.ndarray]) -> int:
    """The task dimension n of a record's ``log``: the width of its ``position_error``."""
    return signals_dimension(log, "position_error", "record.log")


@dataclass(frozen=True)
class IterationRecord:
    """Everything iteration ``iteration`` (j, counted from 0) produced.

    Attributes
    ----------
    iteration : int
        j, counted from 0.
    status : str
        ``"complete"`` or ``"diverged"``.
    diverged_time : float
        Time (s) at which the watchdog stopped the iteration; NaN if complete.
    diverged_reason : str
        One line naming the watchdog rule that fired; empty if complete.
    fallback_count : int
        Control samples where the implicit acceleration scheme found no real solution and
        reused the previous sample's acceleration (docs/model.md#acceleration). 0 for other schemes.
    log : dict[str, ndarray]
        Every entry of :func:`log_signals` of the task's n axes, on the log grid, shape (n_log,) or
        (n_log, n); n = 2 (:data:`LOG_SIGNALS`) or 3, the same n for every array.
    memory : dict[str, ndarray]
        The controller's learned memory *after* this iteration, i.e. the memory iteration j + 1
        starts from (Theta_hat_j, alpha_hat_j for C3; v_j for C2; empty for C1). Each array is
        (n_control, ...) on the control grid. Units are in ``memory_units``.
    memory_units : dict[str, str]
        Unit string for each entry of ``memory``.
    memory_labels : dict[str, tuple[str, ...]]
        Column labels of each (n_control, width) memory entry, e.g. Theta_hat's
        ``("D11", "D12", "C11", "C12", ...)``; optional (from the controller's memory layout).
    """

    iteration: int
    status: str
    diverged_time: float
    diverged_reason: str
    fallback_count: int
    log: dict[str, np.ndarray]
    memory: dict[str, np.ndarray] = field(default_factory=dict)
    memory_units: dict[str, str] = field(default_factory=dict)
    memory_labels: dict[str, tuple[str, ...]] = field(default_factory=dict)

    @property
    def diverged(self) -> bool:
        return self.status == STATUS_DIVERGED
