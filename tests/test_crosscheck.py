"""The MuJoCo cross-check (docs/crosscheck.md): its plant is ilcforce's robot (free motion, the perturbation, the
wall's stiffness), its controller side is ilcforce's loop (the measurement vector), and bad input is one line."""

from __future__ import annotations

import math
import subprocess
from pathlib import Path
import sys

import numpy as np
import pytest

from ilcforce.config_load import load_config
from ilcforce.controllers.nd import M_WIDTH, at_py, compile_law, law_signature
from ilcforce.crosscheck.mujoco_plant import ContactSettings, build_arm
from ilcforce.crosscheck.mujoco_run import crosscheck_config, initial_state
from ilcforce.plants import make_plant
from ilcforce.plants.nd import offsets
from ilcforce.simulate import force_axis

mujoco = pytest.importorskip("mujoco")

#: the robots the cross-check simulates, with the iteration whose true plant each test takes (10: perturbed)
ROBOTS = [("serial2r", 0), ("serial2r", 10), ("serial2r-model", 10), ("arm3", 0), ("arm3", 10)]


def _arm(name: str, iteration: int, **contact):
    config = crosscheck_config(load_config(name))
    true_params = config.plant.true_plant(iteration)
    theta0, _ = initial_state(config, true_params)
    arm = build_arm(true_params, config.wall, force_axis(config.surface.selection), ContactSettings(**contact),
                    config.simulation.sample_time, theta0)
    return config, true_params, arm, theta0


def _ours_rk4(robot, q0, torque, h: float, steps: int) -> np.ndarray:
    """ilcforce's plant (its n-joint kernel: M ddq = tau - b) integrated by classical RK4 with the torque
    ``torque(t)`` held over each step, as ilcforce's loop integrates it; the joint angles after ``steps``."""
    kernel, address = robot.nd_kernel(), robot.address
    n = len(q0)
    o = offsets(n, n)
    out = np.empty(robot.nd_width)

    def accel(q, dq, tau):
        kernel(address, np.ascontiguousarray(q), np.ascontiguousarray(dq), 1, out)
        M = out[o.m:o.m + n * n].reshape(n, n)
        return np.linalg.solve(M, tau - out[o.b:o.b + n])

    q, dq = np.array(q0, dtype=float), np.zeros(n)
    for i in range(steps):
        tau = torque(i * h)
        k1v, k1a = dq, accel(q, dq, tau)
        k2v, k2a = dq + 0.5 * h * k1a, accel(q + 0.5 * h * k1v, dq + 0.5 * h * k1a, tau)
        k3v, k3a = dq + 0.5 * h * k2a, accel(q + 0.5 * h * k2v, dq + 0.5 * h * k2a, tau)
        k4v, k4a = dq + h * k3a, accel(q + h * k3v, dq + h * k3a, tau)
        q = q + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        dq = dq + h / 6.0 * (k1a + 2 * k2a + 2 * k3a + k4a)
    return q


@pytest.mark.parametrize(("name", "iteration"), ROBOTS)
def test_free_motion_agrees_with_ilcforces_plant_to_integration_accuracy(name, iteration):
    """Contact off, no wall: the same open-loop torque (a holding torque plus sines, so the arm swings through
    more than a radian) for 0.3 s at h = 1 ms. Both integrate with classical RK4 and the torque held per step,
    so the two trajectories differ by floating point and by any difference of model (the perturbed link, the
    inertias MuJoCo fuses, gravity): the bound is the RK4 error of ilcforce's own trajectory at this step,
    estimated by Richardson from a run at h / 2 (|q_h - q_h/2| 16/15), which the engines' difference must not
    exceed. The bound is about 1e-10 to 1e-9 rad; the perturbed link's 1.4x mass alone moves the arm by 0.04 to
    0.1 rad here (measured), so a model that differs is found."""
    config, true_params, arm, theta0 = _arm(name, iteration)
    robot = make_plant(true_params)
    n = len(theta0)
    hold = np.array(arm.data.qfrc_bias)  # at rest: the gravity torque at theta0 (MuJoCo's, at set_state)

    def torque(t):
        return hold + 0.5 * np.sin(2 * math.pi * 3.0 * t + np.arange(n))

    h, steps = 1e-3, 300
    arm.model.opt.timestep = h
    arm.model.opt.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT)
    arm.set_state(theta0, np.zeros(n))
    for i in range(steps):
        arm.step(torque(i * h), 1)
    q_mujoco = np.array(arm.data.qpos)
    q_h = _ours_rk4(robot, theta0, torque, h, steps)
    q_half = _ours_rk4(robot, theta0, lambda t: torque(math.floor(t / h + 1e-9) * h), h / 2, 2 * steps)
    integration_error = np.max(np.abs(q_h - q_half)) * 16 / 15
    assert np.max(np.abs(q_h - theta0)) > 0.1, "the torque must move the arm, or the test checks nothing"
    np.testing.assert_allclose(q_mujoco, q_h, rtol=0, atol=integration_error,
                               err_msg=f"{name} (iteration {iteration}): MuJoCo's free motion differs from "
                                       f"ilcforce's by more than RK4's error at h = {h} s")


@pytest.mark.parametrize("name", ["serial2r-model", "arm3"])
def test_the_walls_stiffness_is_k_e_in_equilibrium(name):
    """Held in equilibrium (the torque J_X^T F balances the wall's push and gravity, so the contact point does
    not accelerate and the added mass d / (1 - d) / A exerts nothing), MuJoCo's contact force is K_e times the
    penetration to MuJoCo's solver tolerance (1e-8 relative, its default), along the force axis only."""
    config, _true, arm, theta0 = _arm(name, 0)
    n, fa, w = len(theta0), arm.force_axis, config.wall.sign
    arm.model.opt.gravity[:] = 0.0
    for penetration in (1e-3, 4e-3):
        q = theta0.copy()
        for _ in range(30):  # Newton steps onto the pose penetration deep into the wall
            arm.set_state(q, np.zeros(n))
            push = np.zeros(n)
            push[fa] = config.wall.position + w * penetration - arm.position()[fa]
            q = q + np.linalg.solve(arm.task_jacobian(), push)
        arm.set_state(q, np.zeros(n))
        spring = np.zeros(n)
        spring[fa] = config.wall.stiffness * penetration
        # the torque holding the arm against the spring: the robot feels -w F along the force axis
        arm.data.qfrc_applied[:] = arm.task_jacobian().T @ (w * spring)
        arm.forward()
        assert np.max(np.abs(arm.data.qacc)) < 1e-6, "not in equilibrium: the check would see the added mass"
        np.testing.assert_allclose(arm.contact_force(), spring, rtol=1e-8, atol=1e-9,
                                   err_msg=f"{name}: MuJoCo's wall is not K_e = {config.wall.stiffness} N/m")


def _spy_law():
    """A law that records the measurement vector it is given (into mem_new[k], when it writes) and returns a
    small torque that depends on it, so both loops' states move as a law would move them."""

    def spy(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
        n = tau.shape[0]
        if write:
            for i in range(meas.shape[0]):
                mem_new[k, i] = meas[i]
        for j in range(n):
            tau[j] = gains[j] - 0.1 * meas[j]
            diag[j] = 0.0
        return 0

    return compile_law(spy, law_signature())


class _Spy:
    """A controller whose law is the spy (set on a class of its own: the simulator reads a law from the class)."""

    name = "spy"
    uses_nominal_dynamics = True  # the task-model blocks of eq. (4) are filled, and compared
    nd_scratch = 0

    def __init__(self, hold) -> None:
        self.hold = np.asarray(hold, dtype=np.float64)

    def gains(self):
        return self.hold


@pytest.mark.parametrize("name", ["serial2r-model", "arm3"])
def test_the_measurement_vector_is_the_loops_on_the_same_states(name):
    """ilcforce's n-joint loop runs a spy law for 40 samples (filtered scheme, log every sample); the
    cross-check's sample function is given the loop's true states and true contact force at each sample with
    the same noise. Every entry of the measurement vector (angles, rates, force, nominal P, dP, J_X, the
    filtered estimates, the task model D, C, G) must be the loop's: the same operations in the same order, so
    equal to the last bits bar a fused multiply-add (1e-12 relative)."""
    from ilcforce.crosscheck.sample import SAMPLE_OK, control_sample, filter_width
    from ilcforce.experiment import iteration_inputs
    from ilcforce.simulate import run_iteration

    config = crosscheck_config(load_config(name, {"reference.duration": 0.004, "simulation.log_every": 1}))
    n = config.dimension
    law = _spy_law()
    spy_class = type("SpyController", (_Spy,), {"law": law})
    nominal = make_plant(config.plant.nominal())
    theta0, _ = initial_state(config, config.plant.true_plant(0))
    # the spy's torque: gravity held and the tool pressed into the wall with 5 N, so the contact force is tested
    o = offsets(n, n)
    out = np.empty(nominal.nd_width)
    nominal.nd_kernel()(nominal.address, theta0, np.zeros(n), 2, out)
    jacobian = config.wall.frame(n) @ out[o.j:o.j + n * n].reshape(n, n)
    press = np.zeros(n)
    press[force_axis(config.surface.selection)] = 5.0 * config.wall.sign
    spy = spy_class(out[o.g:o.g + n] + jacobian.T @ press + 0.1 * theta0)
    width = at_py(M_WIDTH, n)
    inputs = iteration_inputs(config, 0, config.reference_samples())
    n_control = config.n_control
    loop_mem = np.zeros((n_control, width))
    record = run_iteration(inputs, spy, np.zeros((n_control, width)), loop_mem)
    assert record.status == "complete"
    log = record.log

    sample = control_sample(law, nominal.nd_kernel())
    wall = config.wall.packed(n)
    s = config.simulation
    beta = 1.0 - math.exp(-2.0 * math.pi * s.filter_hz * s.sample_time)
    ours_mem = np.zeros((n_control, width))
    filters = np.zeros(filter_width(n))
    meas, diag, out_n = np.zeros(width), np.zeros(4 * n), np.empty(nominal.nd_width)
    tau, qm, dqm, fmeas = (np.empty(n) for _ in range(4))
    ref = np.ascontiguousarray(config.reference_samples())
    noise = np.ascontiguousarray(inputs.draws.sensor)
    for k in range(n_control):
        ok = sample(nominal.address, wall, spy.gains(), np.zeros((n_control, width)), ours_mem, ref, noise,
                    s.sample_time, beta, 1, filters, k, np.ascontiguousarray(log["joint_angle"][k]),
                    np.ascontiguousarray(log["joint_rate"][k]), force_axis(config.surface.selection),
                    np.ascontiguousarray(log["contact_force"][k]),
                    meas, diag, out_n, tau, qm, dqm, fmeas)
        assert ok == SAMPLE_OK
        np.testing.assert_allclose(tau, log["torque"][k], rtol=1e-12, atol=1e-14, err_msg=f"torque at k = {k}")
    assert np.any(log["contact_force"][:, force_axis(config.surface.selection)] > 0), "no contact: force untested"
    np.testing.assert_allclose(ours_mem, loop_mem, rtol=1e-12, atol=1e-12,
                               err_msg=f"{name}: the cross-check's measurement vector differs from the loop's")


@pytest.mark.parametrize(("args", "words"), [
    (["no-such-experiment.toml"], "no-such-experiment"),
    (["serial2r-model", "-m", "no-such-method"], "no-such-method"),
    (["paper", "-m", "c2"], "plant.model"),
    (["serial2r-model", "-n", "0"], "--iters"),
    (["serial2r-model", "--damping-ratio", "-1"], "damping ratio"),
    (["serial2r-model", "--no-such-option"], "--no-such-option"),
])
def test_bad_input_is_one_line(args, words):
    result = subprocess.run([sys.executable, "-m", "ilcforce.crosscheck.mujoco_run", *args], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], result.stderr
    assert result.stdout == ""


def test_a_damped_or_rubbing_wall_is_refused_by_name(tmp_path):
    """MuJoCo's contact stands for the wall's spring only: a wall with ilcforce's damper or friction is refused with
    one line, not run on a MuJoCo plant that silently lacks them (its tau_d would still hold the friction)."""
    shipped = Path(__file__).resolve().parent.parent / "experiments"
    for key, value in (("damping", 40.0), ("friction", 0.3)):
        text = (shipped / "serial2r-model.toml").read_text(encoding="utf-8")
        experiment = tmp_path / f"{key}.toml"
        experiment.write_text(text.replace('path = "', f'path = "{shipped}/') + f"\n[wall]\n{key} = {value}\n"
                              if "[wall]" not in text else text.replace("[wall]", f"[wall]\n{key} = {value}"),
                              encoding="utf-8")
        result = subprocess.run([sys.executable, "-m", "ilcforce.crosscheck.mujoco_run", str(experiment), "-n", "1"],
                                capture_output=True, text=True, timeout=120, cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and f"wall.{key} = {value:g}" in lines[0], result.stderr


def test_the_pages_verdict_rule():
    """The page's rule (ilcforce.crosscheck.page): both complete with every number within a factor 2, or both
    diverge at most 2 iterations apart; anything else differs, and says what."""
    from ilcforce.crosscheck.mujoco_run import CrossRow
    from ilcforce.crosscheck.page import verdict

    def rows(count, *, diverged=False, e_f=0.1, h=(1.0, 2.0)):
        out = [CrossRow(j, "complete", 1e-3, e_f, h, math.nan) for j in range(count)]
        if diverged:
            out[-1] = CrossRow(count - 1, "diverged", math.nan, math.nan, (math.nan,) * len(h), 0.5)
        return out

    assert verdict(rows(3), rows(3, e_f=0.19), 3) == "agrees"
    assert verdict(rows(3), rows(3, e_f=0.21), 3) == "differs: e_F"
    assert verdict(rows(3), rows(3, h=(1.0, 4.1)), 3) == "differs: H[1]"
    assert verdict(rows(3), rows(1, diverged=True), 3) == "differs: only MuJoCo's diverged"
    assert verdict(rows(13, diverged=True), rows(14, diverged=True), 20).startswith("agrees (both diverged")
    assert verdict(rows(13, diverged=True), rows(1, diverged=True), 20) == "differs: diverged in j = 12 / 0"
