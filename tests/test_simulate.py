"""The sampled-data simulator: against scipy, determinism, the watchdog, the implicit loop."""

from __future__ import annotations

import math

import numpy as np
import pytest
from numba import njit
from scipy.integrate import solve_ivp

from ilcforce.controllers.base import (DIAG_SIGMA, LAW_SIGNATURE, MEAS_ACCEL, MEAS_DTHETA,
                                       MEAS_FORCE_ACCEL, MEAS_THETA, MemoryController)
from ilcforce.noise import draw_iteration
from ilcforce.plants.fivebar import FiveBar
from ilcforce.simulate import IterationInputs, run_iteration

# Joint-space PD holding the pose that presses 10 mm into the wall (a smooth case: always in contact).
_KP, _KD = 20.0, 1.0


@njit(LAW_SIGNATURE)
def pd_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return (_KP * (gains[0] - meas[MEAS_THETA]) - _KD * meas[MEAS_DTHETA],
            _KP * (gains[1] - meas[MEAS_THETA + 1]) - _KD * meas[MEAS_DTHETA + 1])


@njit(LAW_SIGNATURE)
def zero_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return 0.0, 0.0


@njit(LAW_SIGNATURE)
def huge_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return (1e4 if k >= 5 else 0.0), 0.0


@njit(LAW_SIGNATURE)
def nan_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    return (math.nan if k >= 7 else 0.0), 0.0


@njit(LAW_SIGNATURE)
def quadratic_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    """Torque quadratic in the force-axis acceleration, like eq. (14); logs the acceleration it saw."""
    a = meas[MEAS_ACCEL + 1]
    f2 = meas[MEAS_FORCE_ACCEL + 1]
    diag[DIAG_SIGMA] = a
    diag[DIAG_SIGMA + 1] = f2
    return 0.05 * a + 0.002 * a * a + 0.3, 0.01 * a - 0.001 * a * a + 0.2


class _TestController(MemoryController):
    name = "test"
    uses_nominal_dynamics = False
    memory_layout = {}

    def __init__(self, n_control, law, gains=(0.0,) * 9):
        super().__init__(n_control)
        self.law = law
        self._gains = np.array(gains, dtype=np.float64)

    def gains(self):
        return self._gains


def _inputs(config, iteration=0):
    return IterationInputs(iteration, config.plant.true_plant(iteration), config.plant.links(), config.wall,
                           config.reference_samples(), config.simulation, config.noise,
                           draw_iteration(config.experiment.seed, iteration, config.n_control, config.noise),
                           config.surface.selection)


def _run(config, controller, iteration=0):
    mem_prev, mem_new = controller.begin_iteration(iteration)
    return run_iteration(_inputs(config, iteration), controller, mem_prev, mem_new)


QUIET = {"noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0, "noise.joint_rate": 0.0,
         "noise.force_sensor": 0.0}


def test_pd_against_solve_ivp(short_config):
    """Zero-order-hold PD pressing on the wall, against scipy's RK45 at tight tolerance.

    The reference integrates the same ZOH piecewise (one solve_ivp per control interval), so the two
    differ only by integration error: RK4 at h = 0.1 ms on dynamics whose fastest mode (wall
    stiffness over task inertia, ~50 rad/s) gives local errors ~ (omega h)^5 ~ 1e-12; over 500 steps
    that stays well below 1e-9 rad. Tolerance 1e-8 rad leaves margin without hiding a wrong model.
    """
    config = short_config(**QUIET, **{"reference.duration": 0.05})
    robot = FiveBar(config.plant.links())
    target = robot.inverse_kinematics((0.35, 0.41))  # 10 mm into the wall
    controller = _TestController(config.n_control, pd_law, (*target, *([0.0] * 7)))
    record = _run(config, controller)
    assert record.status == "complete", record.diverged_reason

    wall = config.wall
    ts = config.simulation.sample_time

    def rhs(t, x, tau):
        theta, dtheta = x[:2], x[2:]
        y = robot.forward_kinematics(theta)[1]
        force = (0.0, -wall.contact_force(y))  # the wall pushes back on the robot
        return np.concatenate([dtheta, robot.forward_dynamics(theta, dtheta, tau, force)])

    x = np.concatenate([robot.inverse_kinematics(config.simulation.initial_position), [0.0, 0.0]])
    states = [x]
    for k in range(config.n_control - 1):
        tau = np.array([_KP * (target[0] - x[0]) - _KD * x[2], _KP * (target[1] - x[1]) - _KD * x[3]])
        sol = solve_ivp(rhs, (k * ts, (k + 1) * ts), x, args=(tau,), rtol=1e-11, atol=1e-13, method="DOP853")
        x = sol.y[:, -1]
        states.append(x)
    states = np.array(states)[:: config.simulation.log_every]
    np.testing.assert_allclose(record.log["joint_angle"], states[:, :2], rtol=0, atol=1e-8,
                               err_msg="RK4 ZOH simulation departs from the solve_ivp reference")
    np.testing.assert_allclose(record.log["joint_rate"], states[:, 2:], rtol=0, atol=1e-6,
                               err_msg="joint rates depart from the solve_ivp reference")
    assert record.log["contact_force"][-1, 1] > 1.0, "the PD must press on the wall in this case"


def test_zero_torque_at_rest_stays_at_rest(short_config):
    """No torque, no disturbance, at rest on the wall with zero force: nothing moves.

    The start pose comes from inverse then forward kinematics, so it may sit ~1e-17 m inside the wall;
    that spring force (~1e-14 N) integrates to rates of order 1e-13 rad/s over 0.2 s. 1e-10 rad/s is
    far above that roundoff and far below any real motion.
    """
    config = short_config(**QUIET)
    record = _run(config, _TestController(config.n_control, zero_law))
    assert record.status == "complete"
    np.testing.assert_allclose(record.log["joint_rate"], 0.0, rtol=0, atol=1e-10, err_msg="a resting robot moved")


def test_same_seed_identical_different_seed_differs(short_config):
    config = short_config()
    a = _run(config, _TestController(config.n_control, zero_law))
    b = _run(config, _TestController(config.n_control, zero_law))
    for name in a.log:
        np.testing.assert_array_equal(a.log[name], b.log[name], err_msg=f"{name} differs between identical runs")
    c = _run(short_config(**{"experiment.seed": 1}), _TestController(config.n_control, zero_law))
    assert not np.array_equal(a.log["joint_angle_measured"], c.log["joint_angle_measured"])
    assert not np.array_equal(a.log["disturbance"], c.log["disturbance"])


def test_noise_is_bounded_and_scaled(short_config):
    config = short_config()
    record = _run(config, _TestController(config.n_control, zero_law))
    noise = record.log["joint_angle_measured"] - record.log["joint_angle"]
    assert np.abs(noise).max() <= config.noise.encoder
    assert np.abs(noise).max() > 0.5 * config.noise.encoder, "uniform noise should reach near its bound"
    force_noise = record.log["contact_force_measured"] - record.log["contact_force"]
    assert np.abs(force_noise).max() <= config.noise.force_sensor
    assert np.abs(record.log["disturbance"]).max() <= config.noise.disturbance_amplitude


@pytest.mark.parametrize("law, reason", [(huge_law, "torque bound"), (nan_law, "non-finite")])
def test_watchdog_stops_the_iteration(short_config, law, reason):
    config = short_config()
    record = _run(config, _TestController(config.n_control, law))
    assert record.status == "diverged"
    assert reason in record.diverged_reason
    assert record.diverged_time == pytest.approx((5 if law is huge_law else 7) * config.simulation.sample_time)
    assert np.isnan(record.log["torque"][-1]).all(), "samples after the divergence must be NaN"


def test_implicit_scheme_solves_the_algebraic_loop(short_config):
    """The acceleration the law was given equals the plant's actual acceleration under its torque.

    The law's torque is quadratic in the acceleration it is handed; at each logged sample we recompute
    the true plant's y acceleration for the logged torque with the public API. Both sides are exact
    arithmetic on the same state, so they agree to roundoff (relative 1e-9 of the acceleration scale).
    """
    config = short_config(**QUIET, **{"reference.duration": 0.1})
    record = _run(config, _TestController(config.n_control, quadratic_law))
    assert record.status == "complete"
    robot = FiveBar(config.plant.links())
    a_given = record.log["sliding_surface"][:, 0]
    checked = 0
    for i in range(0, a_given.size, 7):
        theta, dtheta = record.log["joint_angle"][i], record.log["joint_rate"][i]
        tau = record.log["torque"][i]
        y = record.log["position"][i, 1]
        f = np.array([0.0, -config.wall.contact_force(y)])
        ddtheta = robot.forward_dynamics(theta, dtheta, tau, f)
        ddp = robot.jacobian(theta) @ ddtheta + robot.jacobian_derivative(theta, dtheta) @ dtheta
        assert ddp[1] == pytest.approx(a_given[i], rel=1e-9, abs=1e-9), f"loop not closed at log sample {i}"
        checked += 1
    assert checked > 10
    # in contact the force's second derivative follows the stiffness relation
    in_contact = record.log["position"][:, 1] > config.wall.position
    np.testing.assert_allclose(record.log["sliding_surface"][in_contact, 1],
                               config.wall.stiffness * a_given[in_contact], rtol=1e-12,
                               err_msg="ddF != K_e ddy in contact")
    assert record.fallback_count == 0


# --- every plant: determinism, chunking, Ctrl-C, resume -------------------------------------------

PLANTS = ["fivebar", "serial2r"]


def _plant_config(short_config, model, **overrides):
    return short_config(**{"plant.model": model, **overrides})


@pytest.mark.parametrize("model", PLANTS)
@pytest.mark.parametrize("method", ["c1", "c2", "c3"])
def test_every_plant_is_deterministic_and_chunking_changes_no_bit(short_config, model, method):
    """Same inputs, same bits; and the compiled loop's chunking (it returns to Python every
    chunk_steps samples and resumes from its carry vector) leaves every number unchanged."""
    from ilcforce.experiment import make_controller

    config = _plant_config(short_config, model)
    records = []
    for chunk in (None, None, 1, 7, 10 ** 9):
        controller = make_controller(config, method)
        mem_prev, mem_new = controller.begin_iteration(0)
        record = run_iteration(_inputs(config), controller, mem_prev, mem_new, chunk_steps=chunk)
        records.append((record, controller.unfinished_state()))
    first, memory = records[0]
    assert first.status == "complete", first.diverged_reason
    for record, mem in records[1:]:
        assert record.fallback_count == first.fallback_count
        for name in first.log:
            np.testing.assert_array_equal(record.log[name], first.log[name], err_msg=f"{model}/{method}: {name}")
        for key in memory:
            np.testing.assert_array_equal(mem[key], memory[key], err_msg=f"{model}/{method}: memory {key}")


def test_stop_request_takes_effect_within_a_chunk(short_config):
    """Ctrl-C (issue 8, fault 11): run_iteration checks stop_requested between chunks and
    abandons the iteration at once, however long it is."""
    config = short_config(**{"simulation.substeps": 50})
    calls = []

    def stop():
        calls.append(1)
        return len(calls) >= 2

    controller = _TestController(config.n_control, zero_law)
    mem_prev, mem_new = controller.begin_iteration(0)
    with pytest.raises(KeyboardInterrupt):
        run_iteration(_inputs(config), controller, mem_prev, mem_new, stop_requested=stop, chunk_steps=100)
    assert len(calls) == 2, "the iteration went on after the stop request"


@pytest.mark.parametrize("model", PLANTS)
def test_interrupted_then_resumed_run_is_bit_identical(tmp_path, short_config, model):
    """A run stopped mid-iteration (stop_requested between chunks), then resumed, stores exactly
    the numbers of an uninterrupted run, on every plant."""
    from ilcforce import store
    from ilcforce.experiment import run_method

    config = _plant_config(short_config, model)
    run_method(config, "c3", tmp_path / "whole.h5")
    checks = []

    def stop_in_iteration_1():
        checks.append(1)
        # iteration 0 (2001 samples, chunks of 500): 4 checks between chunks + 1 after it is stored;
        # the 7th check is inside iteration 1, which is abandoned
        return len(checks) > 6
    with pytest.raises(KeyboardInterrupt):
        run_method(config, "c3", tmp_path / "cut.h5", stop_requested=stop_in_iteration_1, chunk_steps=500)
    assert store.iterations(tmp_path / "cut.h5") != store.iterations(tmp_path / "whole.h5")
    run_method(config, "c3", tmp_path / "cut.h5", resume=True)
    for j in store.iterations(tmp_path / "whole.h5"):
        a, b = store.read_iteration(tmp_path / "whole.h5", j), store.read_iteration(tmp_path / "cut.h5", j)
        np.testing.assert_array_equal(a.to_numpy(), b.to_numpy(), err_msg=f"{model}: iteration {j}")
        ma, mb = store.read_memory(tmp_path / "whole.h5", j), store.read_memory(tmp_path / "cut.h5", j)
        for key in ma:
            np.testing.assert_array_equal(ma[key], mb[key], err_msg=f"{model}: memory {key} of {j}")
