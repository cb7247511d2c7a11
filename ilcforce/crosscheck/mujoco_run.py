"""The cross-check's iteration loop (docs/crosscheck.md): ilcforce's controllers on ilcforce's task, with MuJoCo
doing the physics, and the same run on ilcforce's own plant beside it.

Per control sample, in Python: MuJoCo's forward dynamics at the current state (with the torque held from the
sample before) gives the joint angles and rates and the contact force (:mod:`ilcforce.crosscheck.mujoco_plant`);
:func:`ilcforce.crosscheck.sample.control_sample` adds the sample's sensor noise, builds the law's measurement
vector from the NOMINAL model and the filtered estimates, and calls the method's compiled ``law``; the
watchdog and the log are the loop's (``ilcforce.loop``: its log layout, its torque bound); then MuJoCo steps
over Ts with the torque and the disturbance's joint force -J_X^T F_v (MuJoCo's Jacobian, F_v at the step's
middle) held. The noise and the disturbance are ilcforce's draws (:func:`ilcforce.noise.draw_iteration`, from
(seed, iteration)); the reference, the record, the desired inputs and the metrics are ilcforce's, and the
controller's ``end_iteration`` learns from the record as in an ordinary run.

The acceleration scheme is "filtered" on both sides: the implicit scheme solves the algebraic loop through
ilcforce's own plant, which a MuJoCo run does not have. :func:`crosscheck_config` sets it.

One iteration of the paper's 2 s at Ts = 0.1 ms is 20,001 calls into MuJoCo and into the law from Python;
:class:`CrossRow` records the wall time each took.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from ilcforce.config import Config
from ilcforce.controllers.base import law_of
from ilcforce.experiment import canonical, make_controller
from ilcforce.metrics import iteration_metrics
from ilcforce.noise import disturbance, draw_iteration
from ilcforce.plants import make_plant
from ilcforce.records import STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord, task_axes
from ilcforce.simulate import complete_record, desired_inputs, force_axis, log_signals
from ilcforce.task import REF_VELOCITY, reference_block

__all__ = ["CROSSCHECK_METHODS", "CrossRow", "crosscheck_config", "mujoco_iterations", "own_iterations", "compare"]

#: the methods whose laws the cross-check runs (every method's law works; these are its table)
CROSSCHECK_METHODS = ("c1", "c2", "c3", "c2-robust", "c3-robust")


@dataclass(frozen=True)
class CrossRow:
    """One iteration's numbers: RMS position and force errors (m, N), settled H per task axis (N), the status
    and, for a MuJoCo iteration, its wall time (s)."""

    iteration: int
    status: str
    position_error_rms: float
    force_error_rms: float
    settled_h: tuple[float, ...]
    diverged_time: float
    seconds: float = math.nan

    @classmethod
    def of(cls, metrics: dict, axes: tuple[str, ...], seconds: float = math.nan) -> CrossRow:
        return cls(int(metrics["iteration"]), str(metrics["status"]), float(metrics["position_error_rms"]),
                   float(metrics["force_error_rms"]),
                   tuple(float(metrics[f"chattering_task_{a}_settled"]) for a in axes),
                   float(metrics["diverged_time"]), seconds)


def crosscheck_config(config: Config, iterations: int | None = None) -> Config:
    """``config`` with the filtered acceleration scheme (module docstring) and, if given, ``iterations``."""
    simulation = dataclasses.replace(config.simulation, acceleration="filtered")
    experiment = config.experiment if iterations is None else dataclasses.replace(config.experiment,
                                                                                   iterations=int(iterations))
    return dataclasses.replace(config, simulation=simulation, experiment=experiment)


def _check(config: Config, method: str) -> str:
    from ilcforce.crosscheck.mujoco_plant import simulates

    method = canonical(method)

    if not simulates(config.plant.nominal()):
        raise ValueError(f"the MuJoCo cross-check has no MuJoCo model of plant.model = {config.plant.model!r}; "
                         "its plants are those read from a model file and the closed forms that give one")
    if config.wall.damping != 0.0 or config.wall.friction != 0.0:
        raise ValueError(f"the MuJoCo cross-check maps the wall's spring onto MuJoCo's contact (docs/crosscheck.md), "
                         f"not its damper or friction: wall.damping = {config.wall.damping:g}, wall.friction = "
                         f"{config.wall.friction:g}; set both to 0 (MuJoCo's own damping is --damping-ratio)")
    if config.simulation.acceleration != "filtered":
        raise ValueError("the cross-check runs the filtered acceleration scheme (crosscheck_config sets it)")
    return method


def initial_state(config: Config, true_params) -> tuple[np.ndarray, np.ndarray]:
    """(theta0, dtheta0) of every iteration, as ilcforce's loop starts it (ilcforce.simulate): inverse
    kinematics of the true plant at the initial position, at rest or with the reference's velocity."""
    n = config.dimension
    robot = make_plant(true_params)
    frame = config.wall.frame(n)
    theta0 = np.asarray(robot.inverse_kinematics(frame.T @ np.asarray(config.simulation.initial_position, dtype=float)),
                        dtype=np.float64)
    dtheta0 = np.zeros(n)
    if config.simulation.initial_velocity == "consistent":
        dtheta0 = np.linalg.solve(frame @ robot.jacobian(theta0),
                                  reference_block(config.reference_samples(), REF_VELOCITY, n)[0])
    return theta0, dtheta0


def mujoco_iterations(config: Config, method: str, contact=None, arms: dict | None = None):
    """Yield (record, metrics, seconds) per iteration of ``method`` on MuJoCo's plant, stopping after a
    diverged one. ``config`` must run the filtered scheme (:func:`crosscheck_config`); ``contact`` is a
    :class:`~ilcforce.crosscheck.mujoco_plant.ContactSettings`; ``arms`` (true plant -> MujocoArm) a cache
    the caller may share between methods of one experiment."""
    from ilcforce.crosscheck.mujoco_plant import ContactSettings, build_arm
    from ilcforce.crosscheck.sample import SAMPLE_OK, control_sample, filter_width
    from ilcforce import loop as nd_loop

    method = _check(config, method)
    contact = contact if contact is not None else ContactSettings()
    arms = arms if arms is not None else {}
    controller = make_controller(config, method)
    law = law_of(controller)
    n = config.dimension
    s = config.simulation
    fa = force_axis(config.surface.selection)
    nominal = make_plant(config.plant.nominal())
    p_nom = nominal.address
    sample = control_sample(law, nominal.nd_kernel())
    wall = config.wall.packed(n)
    ref = np.ascontiguousarray(config.reference_samples())
    ref_log = ref[::s.log_every]
    n_control = ref.shape[0]
    n_steps = n_control - 1
    t_control = np.arange(n_control) * s.sample_time
    beta = 1.0 - math.exp(-2.0 * math.pi * s.filter_hz * s.sample_time)
    nominal_dyn = int(controller.uses_nominal_dynamics)
    columns = nd_loop.log_columns(n)
    desired: dict = {}
    for j in range(config.experiment.iterations):
        started = time.perf_counter()
        true_params = config.plant.true_plant(j)
        theta0, dtheta0 = initial_state(config, true_params)
        if true_params not in arms:
            arms[true_params] = build_arm(true_params, config.wall, fa, contact, s.sample_time, theta0)
        arm = arms[true_params]
        draws = draw_iteration(config.experiment.seed, j, n_control, config.noise, n)
        noise = np.ascontiguousarray(draws.sensor)
        # F_v (task frame) at each step's middle, held over the step; the log shows it at the sample, as the loop's
        forces_mid = disturbance(t_control + 0.5 * s.sample_time, draws, config.noise)
        forces_at = disturbance(t_control, draws, config.noise)
        mem_prev, mem_new = controller.begin_iteration(j)
        gains = np.ascontiguousarray(controller.gains(), dtype=np.float64)
        log = np.full((s.n_log(config.reference.duration), nd_loop.log_width(n)), np.nan)
        filters = np.zeros(filter_width(n))
        meas = np.zeros(_meas_width(n))
        diag = np.zeros(4 * n + getattr(controller, "nd_scratch", 0))
        out_n = np.empty(nominal.nd_width)
        tau, qm, dqm, fmeas = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
        arm.set_state(theta0, dtheta0)
        status, t_fail, why = STATUS_COMPLETE, math.nan, ""
        for k in range(n_control):
            arm.forward()
            th = np.array(arm.data.qpos)
            d = np.array(arm.data.qvel)
            force = arm.contact_force()
            ok = sample(p_nom, wall, gains, mem_prev, mem_new, ref, noise, s.sample_time, beta,
                                nominal_dyn, filters, k, th, d, fa, force, meas, diag, out_n, tau, qm, dqm, fmeas)
            why = ("a pose outside the nominal model's working mode" if ok != SAMPLE_OK
                   else "a non-finite state or torque" if not np.all(np.isfinite(tau))
                   else "|tau| above the torque bound" if np.max(np.abs(tau)) > s.torque_bound else "")
            if why:
                status, t_fail = STATUS_DIVERGED, float(t_control[k])
                break
            J = arm.task_jacobian()
            if k % s.log_every == 0:
                row = log[k // s.log_every]
                X = arm.position()
                for name, value in (("joint_angle", th), ("joint_rate", d), ("joint_angle_measured", qm),
                                    ("joint_rate_measured", dqm), ("position", X), ("velocity", J @ d),
                                    ("contact_force", force), ("contact_force_measured", fmeas),
                                    ("disturbance", forces_at[k]), ("torque", tau), ("sliding_surface", diag[:n])):
                    row[columns[name]:columns[name] + n] = value
                try:
                    row[columns["task_input"]:columns["task_input"] + n] = np.linalg.solve(J.T, tau)  # J_X^-T tau
                except np.linalg.LinAlgError:
                    pass  # NaN, as the loop's
                row[nd_loop.log_fallbacks(n)] = 0.0  # no implicit scheme, no fallback
            if k == n_steps:
                break
            arm.step(tau - J.T @ forces_mid[k], contact.steps_per_sample)
            if not (np.all(np.isfinite(arm.data.qpos)) and np.all(np.isfinite(arm.data.qvel))):
                status, t_fail, why = STATUS_DIVERGED, float(t_control[k + 1]), "a non-finite state or torque"
                break
        signals = log_signals(t_control, s.log_every, log, ref, config.surface.selection)
        reason = f"{why} at t = {t_fail:.4f} s" if status == STATUS_DIVERGED else ""
        record = IterationRecord(j, status, t_fail, reason, 0, signals)
        controller.end_iteration(record)  # the between-iteration learning sees the finished iteration
        if true_params not in desired:
            desired[true_params] = desired_inputs(true_params, config.wall, ref_log)
        memory = controller.learned_state() if status == STATUS_COMPLETE else controller.unfinished_state()
        completed = complete_record(record, desired[true_params], memory, controller.learned_units())
        yield completed, iteration_metrics(completed), time.perf_counter() - started
        if status == STATUS_DIVERGED:
            return


def _meas_width(n: int) -> int:
    from ilcforce.controllers.nd import M_WIDTH, at_py

    return at_py(M_WIDTH, n)


def own_iterations(config: Config, method: str):
    """Yield the metrics of each iteration of ``method`` on ilcforce's own plant (the ordinary run, not stored)."""
    from ilcforce.experiment import simulate_iterations

    for record in simulate_iterations(config, canonical(method)):
        yield iteration_metrics(record)


def compare(config: Config, method: str, contact=None, arms: dict | None = None,
            on_row=None) -> tuple[list[CrossRow], list[CrossRow]]:
    """(ilcforce's rows, MuJoCo's rows) of ``method`` over the iterations of ``config`` (filtered, same seed);
    ``on_row(which, row)`` is told each row as it comes ("ours" first, then "mujoco")."""
    axes = task_axes(config.dimension)
    ours, theirs = [], []
    for metrics in own_iterations(config, method):
        ours.append(CrossRow.of(metrics, axes))
        if on_row is not None:
            on_row("ours", ours[-1])
    for _record, metrics, seconds in mujoco_iterations(config, method, contact, arms):
        theirs.append(CrossRow.of(metrics, axes, seconds))
        if on_row is not None:
            on_row("mujoco", theirs[-1])
    return ours, theirs


def _cell(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{value:.3g}"


def _status(row: CrossRow | None) -> str:
    if row is None:
        return "not run"
    return row.status if row.status == STATUS_COMPLETE else f"diverged at {row.diverged_time:.4f} s"


def table_lines(ours: list[CrossRow], theirs: list[CrossRow], axes: tuple[str, ...]) -> list[str]:
    """The side-by-side table, one line per iteration (ilcforce's value, then MuJoCo's, in each column)."""
    head = ["j", "e_P rms ours", "MuJoCo", "e_F rms ours", "MuJoCo",
            *(f"{name} {who}" for a in axes for name, who in ((f"H_{a} settled", "ours"), ("", "MuJoCo"))),
            "status ours", "status MuJoCo", "MuJoCo s"]
    head = [h.strip() for h in head]
    rows = []
    for j in range(max(len(ours), len(theirs))):
        o = ours[j] if j < len(ours) else None
        m = theirs[j] if j < len(theirs) else None

        def pick(row, attr, index=None):
            if row is None:
                return "-"
            value = getattr(row, attr)
            return _cell(value if index is None else value[index])

        rows.append([str(j), pick(o, "position_error_rms"), pick(m, "position_error_rms"),
                     pick(o, "force_error_rms"), pick(m, "force_error_rms"),
                     *(cell for i in range(len(axes)) for cell in (pick(o, "settled_h", i), pick(m, "settled_h", i))),
                     _status(o), _status(m), pick(m, "seconds")])
    widths = [max(len(r[c]) for r in [head, *rows]) for c in range(len(head))]
    return ["  ".join(cell.rjust(w) for cell, w in zip(r, widths)) for r in [head, *rows]]


class _OneLineParser:
    """argparse whose usage errors are one line and exit 2 (ilcforce's rule for bad input)."""

    @staticmethod
    def make(prog: str, description: str):
        import argparse

        class Parser(argparse.ArgumentParser):
            def error(self, message):  # noqa: D401 - argparse's hook
                print(f"error: {message} (see `{self.prog} --help`)", file=sys.stderr)
                raise SystemExit(2)

        return Parser(prog=prog, description=description)


def main(argv: list[str] | None = None) -> int:
    """``python -m ilcforce.crosscheck.mujoco_run EXPERIMENT -m METHOD -n N``: the per-iteration table of
    ilcforce's run and MuJoCo's of one method (docs/crosscheck.md)."""
    from ilcforce.config import ConfigError
    from ilcforce.config_load import load_config
    from ilcforce.crosscheck.mujoco_plant import ContactSettings, describe

    parser = _OneLineParser.make("python -m ilcforce.crosscheck.mujoco_run", __doc__.splitlines()[0])
    parser.add_argument("experiment", help="experiment file (or a shipped experiment's name)")
    parser.add_argument("-m", "--method", default="c2", help=f"one method with an n-axis law, e.g. "
                                                             f"{', '.join(CROSSCHECK_METHODS)} (default c2)")
    parser.add_argument("-n", "--iters", type=int, default=5, help="iterations (default 5)")
    parser.add_argument("--seed", type=int, default=None, help="random seed (default: the experiment's)")
    parser.add_argument("--damping-ratio", type=float, default=ContactSettings.damping_ratio,
                        help="the MuJoCo wall's damping ratio zeta (default 0: the undamped spring of ilcforce's wall)")
    parser.add_argument("--impedance", type=float, default=ContactSettings.impedance,
                        help=f"MuJoCo's flat solimp d (default {ContactSettings.impedance:g})")
    parser.add_argument("--integrator", default=ContactSettings.integrator, help="MuJoCo's integrator (default RK4)")
    args = parser.parse_args(argv)
    try:
        if args.iters < 1:
            raise ValueError(f"--iters must be >= 1, got {args.iters}")
        contact = ContactSettings(args.damping_ratio, args.impedance, args.integrator)
        overrides = {} if args.seed is None else {"experiment.seed": args.seed}
        config = crosscheck_config(load_config(args.experiment, overrides), args.iters)
        method = _check(config, args.method)
        print(f"{config.experiment.name} / {method}, seed {config.experiment.seed}, {args.iters} iteration(s), "
              "filtered acceleration scheme: ilcforce's plant first, then MuJoCo's", file=sys.stderr, flush=True)
        arms: dict = {}
        ours, theirs = compare(config, method, contact, arms)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"error: {' '.join(str(exc).split()) or type(exc).__name__}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print(f"{config.experiment.name} / {method} (seed {config.experiment.seed}): RMS errors (m, N) and settled H (N), "
          "ilcforce's plant beside MuJoCo's")
    print("\n".join(table_lines(ours, theirs, task_axes(config.dimension))))
    for arm in arms.values():
        print(describe(arm, contact))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
