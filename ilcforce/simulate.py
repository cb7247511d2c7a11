"""The sampled-data simulator: one iteration of one controller on the true plant (docs/model.md#acceleration, docs/model.md#sampling).

Blocks and their doors (Drake style): the **plant** (any model of ``ilcforce.plants``, through its
compiled kernels) and the **wall** (``ilcforce.task``) are integrated with fixed-step RK4 in the
compiled loop of ``ilcforce.loop``; the **controller** supplies only its
compiled law (``ilcforce.controllers.base``); this module holds the zero-order hold, the sensors,
the acceleration estimates, the watchdog and the logger. The plant never calls the controller and
the controller never integrates.

Per control sample k (t_k = k Ts), inside one compiled loop:

1. true plant terms at the sample: Dq^-1, Cq dtheta, J, dJ dtheta, contact force, disturbance;
2. measurements: angles, rates and force plus bounded noise; P, dP (and D, C, G if the law asks)
   from the *nominal* model at the measured state;
3. acceleration estimates (docs/model.md#acceleration):
   * ``implicit``: the law's torque is a polynomial of degree <= 2 in the force-axis acceleration
     a (eq. 14 is quadratic through Phi^T Gamma Phi sigma). The simulator evaluates the law at
     a = -1, 0, 1 m/s^2 (without writing memory), recovers tau(a) = tau0 + tau1 a + tau2 a^2 exactly,
     and solves a = p0 + q . tau(a), where p0 + q . tau is the true plant's force-axis acceleration
     for torque tau. Of the two roots it takes the one continuous with the linear case. Without a
     real root the previous sample's a is used and the event counted. dF and ddF follow from
     F = K_e (y - y_e) in contact.
   * ``filtered``: first-order low-pass filtered differences (cut-off ``filter_hz``) of the measured
     dP, of the measured force (-> dF) and of the filtered dF (-> ddF); a raw force is never
     differenced twice.
4. the law is evaluated once more with ``write=True`` (memory update) and its torque held for Ts;
5. watchdog: non-finite values, |tau| above ``torque_bound`` or a pose outside the working mode stop
   the iteration ("diverged"), recording the sample;
6. RK4 over Ts in ``substeps`` steps on the true plant, the disturbance evaluated at stage times.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ilcforce.controllers.base import Controller, law_of
from ilcforce.noise import IterationDraws, NoiseModel, disturbance
from ilcforce.plants import make_plant
from ilcforce.records import LOG_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord
from ilcforce.task import REF_FORCE, REF_POSITION, REF_VELOCITY, Wall, reference_block

ACCELERATION_SCHEMES = {"implicit": 0, "filtered": 1}
#: what the implicit scheme does where its quadratic has no usable root
IMPLICIT_FALLBACKS = {"previous": 0, "least_residual": 1}
#: each iteration's initial velocity: at rest, or the velocity the reference asks for
INITIAL_VELOCITIES = ("rest", "consistent")

# watchdog outcomes, as ilcforce.loop returns them (kept here so importing this module compiles nothing)
_RUN_OK, _RUN_NONFINITE, _RUN_TORQUE_BOUND, _RUN_WORKING_MODE, _RUN_CONTINUE = 0, 1, 2, 3, 4
DIVERGENCE_REASONS = {
    _RUN_NONFINITE: "a non-finite state or torque",
    _RUN_TORQUE_BOUND: "|tau| above the torque bound",
}

#: RK4 steps per chunk of the compiled loop: it returns to Python this often so that Ctrl-C takes
#: effect at once whatever ``substeps`` is. A return costs about 0.3 ms (numba
#: re-types about 20 arguments, four of them function pointers); 32768 steps take about 50 ms, so a
#: chunk costs under 1% and Ctrl-C waits at most one chunk. The paper's 20000 steps are one chunk.
CHUNK_RK4_STEPS = 32768


@dataclass(frozen=True)
class SimulationSettings:
    """Sampling, integration, acceleration scheme and watchdog (docs/model.md#sampling, docs/model.md#acceleration, docs/model.md#watchdog)."""

    sample_time: float = 1e-4  # Ts, zero-order-hold control period, s
    substeps: int = 1  # RK4 steps per control period
    log_every: int = 10  # log every this many control samples (1 ms at the default Ts)
    acceleration: str = "implicit"  # "implicit" (resolve the algebraic loop) or "filtered"
    filter_hz: float = 50.0  # cut-off of the first-order filters of the "filtered" scheme, Hz
    torque_bound: float = 1e3  # watchdog bound on |tau|, N m
    initial_position: tuple[float, ...] = (0.35, 0.40)  # P(0), m (in the wall's frame for a spatial arm: u, v, n)
    # "rest": dP(0) = 0 (the paper says nothing); "consistent": dP(0) = dP_d(0), i.e. dx(0) = dx_d(0)
    # and dy(0) = w dF_yd(0) / K_e, removing the t = 0 mismatch of sigma
    initial_velocity: str = "rest"
    # implicit scheme without a usable root: "previous" reuses the last sample's acceleration;
    # "least_residual" takes the minimiser of the loop residual (the parabola's vertex), which is
    # continuous where the two roots merge and vanish
    implicit_fallback: str = "previous"

    def __post_init__(self) -> None:
        if self.acceleration not in ACCELERATION_SCHEMES:
            raise ValueError(f"simulation.acceleration must be one of {', '.join(ACCELERATION_SCHEMES)}, "
                             f"got {self.acceleration!r}")
        if self.initial_velocity not in INITIAL_VELOCITIES:
            raise ValueError(f"simulation.initial_velocity must be one of {', '.join(INITIAL_VELOCITIES)}, "
                             f"got {self.initial_velocity!r}")
        if self.implicit_fallback not in IMPLICIT_FALLBACKS:
            raise ValueError(f"simulation.implicit_fallback must be one of {', '.join(IMPLICIT_FALLBACKS)}, "
                             f"got {self.implicit_fallback!r}")
        for name in ("sample_time", "filter_hz", "torque_bound"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"simulation.{name} must be finite and positive, got {v!r}")
        for name in ("substeps", "log_every"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"simulation.{name} must be an integer >= 1, got {v!r}")

    def n_control(self, duration: float) -> int:
        """Number of control samples on [0, duration], both ends included."""
        steps = duration / self.sample_time
        n = int(round(steps))
        if n < 1 or abs(steps - n) > 1e-9 * max(1.0, steps):
            raise ValueError(f"simulation.sample_time = {self.sample_time:g} s does not divide the horizon "
                             f"reference.duration = {duration:g} s")
        return n + 1

    def n_log(self, duration: float) -> int:
        n = self.n_control(duration) - 1
        if n % self.log_every:
            raise ValueError(f"simulation.log_every = {self.log_every} does not divide the {n} control steps "
                             f"of the horizon")
        return n // self.log_every + 1


@dataclass(frozen=True)
class IterationInputs:
    """Everything that defines one iteration apart from the controller.

    ``reference`` is the (n_control, 12) array of :meth:`ilcforce.task.Reference.sample`;
    ``draws`` the iteration's disturbance and sensor noise; ``selection`` the diagonal of S.
    ``first_chunk``, if given, is ``(k1, chunk_disturbance(self, 0, k1))``, made ahead of time
    (:func:`prepare_first_chunk`); :func:`run_iteration` uses it when its first chunk ends at k1.
    ``setup``, if given, is the set-up before the loop made ahead of time (:func:`prepare_setup`).
    """

    iteration: int
    true_plant: object  # parameters of any plant model (ilcforce.plants), e.g. FiveBarParams
    nominal_plant: object
    wall: Wall
    reference: np.ndarray
    settings: SimulationSettings
    noise: NoiseModel
    draws: IterationDraws
    selection: tuple[float, ...]
    first_chunk: tuple[int, np.ndarray] | None = None
    setup: IterationSetup | None = None  # made ahead (prepare_setup); run_iteration's own otherwise


def chunk_steps_default(settings: SimulationSettings) -> int:
    """Control samples per chunk of the compiled loop when the caller does not say (about
    :data:`CHUNK_RK4_STEPS` RK4 steps)."""
    return max(1, CHUNK_RK4_STEPS // settings.substeps)


def chunk_disturbance(inputs: IterationInputs, k0: int, k1: int) -> np.ndarray:
    """F_v (N) at the half-step times of control samples k0 .. k1 - 1 and their RK4 stages, shape
    (2 substeps (min(k1, n_control - 1) - k0) + 1, 2). Made per chunk: at substeps = 1000 the whole
    iteration's would be 40 million rows."""
    s = inputs.settings
    n_control = inputs.reference.shape[0]
    h = s.sample_time / s.substeps
    stages = np.arange(2 * s.substeps * k0, 2 * s.substeps * min(k1, n_control - 1) + 1)
    return np.ascontiguousarray(disturbance(stages * (0.5 * h), inputs.draws, inputs.noise))


def prepare_first_chunk(inputs: IterationInputs, chunk_steps: int | None = None) -> IterationInputs:
    """``inputs`` with the disturbance of its first chunk made now (e.g. in another thread, while
    the previous iteration simulates); the numbers are those :func:`run_iteration` would make."""
    chunk = chunk_steps if chunk_steps is not None else chunk_steps_default(inputs.settings)
    return dataclasses.replace(inputs, first_chunk=(chunk, chunk_disturbance(inputs, 0, chunk)))


def force_axis(selection) -> int:
    """Index of the single force-controlled axis of S = diag(selection)."""
    s = [float(v) for v in selection]
    if sorted(s) != [0.0] * (len(s) - 1) + [1.0]:
        raise ValueError(f"surface.selection must select exactly one force axis, e.g. [0, 1]; got {list(selection)}")
    return s.index(1.0)


@dataclass(frozen=True)
class IterationSetup:
    """What an iteration's compiled loop is called with, apart from the controller's gains and memory
    and the buffers the loop writes (made by :func:`run_iteration`): read-only, for one controller."""

    controller: object
    ref: np.ndarray
    t_control: np.ndarray
    true_robot: object
    nominal_robot: object
    wall: np.ndarray
    sensor: np.ndarray
    fset: np.ndarray
    iset: np.ndarray
    n_log: int
    initial_state: tuple  # (theta0, dtheta0), the loop's carry made from it
    simulate_chunk: Callable
    kernels: tuple  # numba's loop: the law's and the plants' kernels, its first arguments
    n: int = 2  # joints = task axes


def _setup(inputs: IterationInputs, controller) -> IterationSetup:
    """The set-up of the loop (``ilcforce.loop``): the reference, the log grid's length, the control grid, the
    true and nominal robots, the initial state on the true plant, the packed settings (the wall's frame R after
    (y_e, K_e, w), then its damper and friction: ``Wall.packed``; the plants' kernel buffers' sizes after the
    settings) and the compiled loop to call."""
    from ilcforce.compiled import aot  # loop: numba's, loaded on first use only

    s = inputs.settings
    ref = np.ascontiguousarray(inputs.reference, dtype=np.float64)
    n_control = ref.shape[0]
    n_log = (n_control - 1) // s.log_every + 1
    t_control = np.arange(n_control) * s.sample_time
    fset = np.array([s.sample_time, 1.0 - math.exp(-2.0 * math.pi * s.filter_hz * s.sample_time), s.torque_bound])
    true_robot, nominal_robot = make_plant(inputs.true_plant), make_plant(inputs.nominal_plant)
    n = true_robot.dimension
    frame = inputs.wall.frame(n)
    theta0 = true_robot.inverse_kinematics(frame.T @ np.asarray(s.initial_position, dtype=np.float64))
    dtheta0 = np.zeros(n)
    if s.initial_velocity == "consistent":  # dX(0) = dX_d(0) on the true plant
        dtheta0 = np.linalg.solve(frame @ true_robot.jacobian(theta0), reference_block(ref, REF_VELOCITY, n)[0])
    iset = np.array([s.substeps, s.log_every, ACCELERATION_SCHEMES[s.acceleration],
                     int(controller.uses_nominal_dynamics), force_axis(inputs.selection),
                     IMPLICIT_FALLBACKS[s.implicit_fallback], true_robot.nd_width, nominal_robot.nd_width,
                     getattr(controller, "nd_scratch", 0)], dtype=np.int64)
    wall = inputs.wall.packed(n)
    # the ahead-of-time compiled loop of this law and plant (no numba in the process), or numba's
    # with the law and the plant's kernels as arguments: the same code, the same numbers
    simulate_chunk, kernels = aot.simulator(controller, type(true_robot), type(nominal_robot)), ()
    if simulate_chunk is None:
        from ilcforce import loop  # numba's, loaded on first use only

        simulate_chunk = loop.simulator(n)
        kernels = (law_of(controller), true_robot.nd_kernel(), nominal_robot.nd_kernel())
    return IterationSetup(controller, ref, t_control, true_robot, nominal_robot, wall,
                          np.ascontiguousarray(inputs.draws.sensor), fset, iset, n_log,
                          (np.asarray(theta0, dtype=np.float64), np.asarray(dtheta0, dtype=np.float64)),
                          simulate_chunk, kernels, n)


def prepare_setup(inputs: IterationInputs, controller) -> IterationInputs:
    """``inputs`` with the set-up :func:`run_iteration` would make before its loop (the robots, the
    initial state, the settings' arrays, the compiled loop to call) made now for ``controller``,
    e.g. in another thread while the previous iteration simulates: the iteration then starts at once
    when the previous one ends. Used by every run of these inputs with this controller (nothing in
    it is written); the same numbers."""
    return dataclasses.replace(inputs, setup=_setup(inputs, controller))


def run_iteration(inputs: IterationInputs, controller: Controller, mem_prev: np.ndarray,
                  mem_new: np.ndarray, stop_requested: Callable[[], bool] | None = None,
                  chunk_steps: int | None = None, turns=None) -> IterationRecord:
    """Simulate one iteration; the controller's memory buffers are read and written in place.

    Returns the :class:`~ilcforce.records.IterationRecord` without ``memory`` (the iteration loop
    attaches the controller's learned state) and with ``desired_torque`` left for the caller via
    :func:`desired_inputs` (it depends only on the true plant, so it is cached there).

    The compiled loop runs in chunks of ``chunk_steps`` control samples (default: about
    :data:`CHUNK_RK4_STEPS` RK4 steps); between chunks Python handles signals, and if
    ``stop_requested()`` is true the iteration is abandoned with KeyboardInterrupt. ``turns``
    (:class:`ilcforce.pipeline.Turns`), if given, is told when the compiled loop runs.
    """
    from ilcforce import loop  # numba's (loaded on first use only) and the loop's constants

    s = inputs.settings
    setup = inputs.setup
    if setup is None or setup.controller is not controller:
        setup = _setup(inputs, controller)
    ref, t_control = setup.ref, setup.t_control
    # what the loop writes is made here, for this run only: a set-up may serve several
    log = np.full((setup.n_log, loop.log_width(setup.n)), np.nan)
    carry = loop.new_carry(*setup.initial_state)
    n_control = ref.shape[0]
    gains = np.ascontiguousarray(controller.gains(), dtype=np.float64)
    head = (*setup.kernels, setup.true_robot.address, setup.nominal_robot.address, setup.wall, gains, mem_prev,
            mem_new, ref)
    # the loop's scratch: made here and held for every chunk's call (the loop views it without an owner)
    work = np.zeros(loop.work_width(setup.n, setup.iset))
    tail = (setup.sensor, setup.fset, setup.iset, log, carry, work)
    simulate_chunk = setup.simulate_chunk
    chunk = chunk_steps if chunk_steps is not None else chunk_steps_default(s)
    k = 0
    while True:
        if k == 0 and inputs.first_chunk is not None and inputs.first_chunk[0] == chunk:
            forces = inputs.first_chunk[1]
        else:
            forces = chunk_disturbance(inputs, k, k + chunk)
        if turns is not None:
            turns.enter()
        try:
            status, k_fail = simulate_chunk(*head, forces, *tail, k, k + chunk)
        finally:
            if turns is not None:
                turns.leave()
        k += chunk
        if status != loop.RUN_CONTINUE:
            break
        if stop_requested is not None and stop_requested():
            raise KeyboardInterrupt
    fallback = int(carry[loop.carry_fallback(setup.n)])
    signals = log_signals(t_control, s.log_every, log, ref, inputs.selection)
    if status == loop.RUN_OK:
        return IterationRecord(inputs.iteration, STATUS_COMPLETE, math.nan, "", fallback, signals)
    t_fail = float(t_control[min(k_fail, n_control - 1)])
    why = DIVERGENCE_REASONS.get(status) or f"a pose outside {setup.true_robot.working_mode}"
    reason = f"{why} at t = {t_fail:.4f} s"
    return IterationRecord(inputs.iteration, STATUS_DIVERGED, t_fail, reason, fallback, signals)


def desired_inputs(plant, wall: Wall, reference_log: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tau_d and J^-T tau_d along the desired motion (docs/model.md#metrics, Table 3's H).

    tau_d = Dq ddtheta_d + Cq dtheta_d + G_q + J^T (w F_d) is the inverse dynamics (eq. 1) of
    ``plant`` (parameters of any model) along P_d(t) = (x_d, y_e + w F_yd / K_e), including the
    desired contact force, so the wall's reaction -w F_d is balanced: the plant's ``desired_inputs``.
    On a wall with friction F_d also holds, in the plane, the friction the desired motion meets (mu F_d,n
    against the desired in-plane velocity, :func:`desired_friction`), so tau_d stays the input that moves
    the true plant along P_d. ``reference_log`` is (n_log, 6 n); returns two (n_log, n) arrays (N m, N).
    """
    robot = make_plant(plant)
    ref = np.ascontiguousarray(reference_log, dtype=np.float64)
    if wall.friction != 0.0:
        ref = desired_friction(wall, ref, robot.dimension)
    return robot.desired_inputs(wall.frame(robot.dimension), float(wall.sign), ref)


def desired_friction(wall: Wall, reference: np.ndarray, n: int) -> np.ndarray:
    """``reference`` (rows, 6 n; ilcforce.task's layout) with the wall's friction along the desired motion in its
    force block's in-plane columns, in the convention of F (the force the end-effector applies: F = -w f, f the
    force on the robot): F_i = w mu F_d,n tanh(|V| / v_eps) V_i / |V|, V the desired in-plane velocity, F_d,n
    the desired normal force (the frame's last axis, ``Wall.frame``), the law of ``ilcforce.ndof.contact.drift``
    (``ilcforce.task.friction_scale``, here in numpy on the whole grid). A copy."""
    out = np.array(reference, dtype=np.float64)
    force = reference_block(out, REF_FORCE, n)  # a view into out
    velocity = reference_block(out, REF_VELOCITY, n)[:, :n - 1]
    speed = np.sqrt(np.sum(velocity * velocity, axis=1))
    moving = speed > 0.0
    scale = np.zeros_like(speed)
    scale[moving] = np.tanh(speed[moving] / wall.friction_velocity) / speed[moving]
    normal = np.maximum(force[:, n - 1], 0.0)
    force[:, :n - 1] = wall.sign * wall.friction * (normal * scale)[:, None] * velocity
    return np.ascontiguousarray(out)


def complete_record(record: IterationRecord, desired: tuple[np.ndarray, np.ndarray], memory: dict,
                    memory_units: dict) -> IterationRecord:
    """Attach tau_d (NaN after a divergence, like the other logs) and the learned memory."""
    log = dict(record.log)
    valid = np.isfinite(log["torque"][:, :1])
    log["desired_torque"] = np.where(valid, desired[0], np.nan)
    log["desired_task_input"] = np.where(valid, desired[1], np.nan)
    missing = set(LOG_SIGNALS) - set(log)
    if missing:
        raise RuntimeError(f"record lacks log signals {sorted(missing)}")
    return IterationRecord(record.iteration, record.status, record.diverged_time, record.diverged_reason,
                           record.fallback_count, log, memory, memory_units)


def log_signals(t_control: np.ndarray, log_every: int, log: np.ndarray, ref: np.ndarray, selection) -> dict:
    """The log signals of an iteration from the loop's log buffer (fresh per iteration)."""
    from ilcforce import loop  # the buffer's layout (no numba)

    n = len(selection)
    out = {"time": t_control[::log_every].copy()}
    columns = loop.log_columns(n)
    for name, col in columns.items():
        out[name] = log[:, col:col + n].copy()
    out["implicit_fallbacks"] = log[:, loop.log_fallbacks(n)].copy()
    sel = np.asarray(selection, dtype=np.float64)
    ref_log = ref[::log_every]
    out["position_error"] = (1.0 - sel) * (reference_block(ref_log, REF_POSITION, n) - out["position"])  # eq. (6)
    out["force_error"] = sel * (reference_block(ref_log, REF_FORCE, n) - out["contact_force"])  # eq. (7)
    return out
