"""The wall's damper and friction (docs/model.md#wall): physics of the contact law the loop integrates.

A free bounce (no torque after a short push, no noise, no gravity on the five-bar) tests the damper: without
it the wall gives back every joule, with it the robot leaves slower and the loss is the damper's work; a
strong damper's clamp (the wall never pulls) is seen at work. A press-and-slide against scipy tests the
friction and the damper inside the dynamics, and the log's friction against Coulomb's law. Bad values are one
line and exit 2 from the command line.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba import njit

from ilcforce.controllers.base import MemoryController
from ilcforce.controllers.nd import law_signature
from ilcforce.noise import draw_iteration
from ilcforce.plants.fivebar import FiveBar
from ilcforce.simulate import IterationInputs, run_iteration
from zohkit import KD as _KD, KP as _KP, pd_law, pd_reference

QUIET = {"noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0, "noise.joint_rate": 0.0,
         "noise.force_sensor": 0.0}
#: the push: 20 ms of the joint torque that pushes 5 N into the wall at the start pose, then nothing
PUSH_SAMPLES, PUSH_FORCE = 200, 5.0


@njit(law_signature())
def push_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    on = 1.0 if k < 200 else 0.0  # PUSH_SAMPLES
    tau[0] = on * gains[0]
    tau[1] = on * gains[1]
    return 0


class _TestController(MemoryController):
    name = "test"
    uses_nominal_dynamics = False
    memory_layout = {}

    def __init__(self, n_control, gains):
        super().__init__(n_control)
        self._gains = np.array(gains, dtype=np.float64)

    def gains(self):
        return self._gains


def _run(config, law, gains):
    controller = type("TestController", (_TestController,), {"law": staticmethod(law)})(config.n_control, gains)
    mem_prev, mem_new = controller.begin_iteration(0)
    inputs = IterationInputs(0, config.plant.true_plant(0), config.plant.links(), config.wall,
                             config.reference_samples(), config.simulation, config.noise,
                             draw_iteration(config.experiment.seed, 0, config.n_control, config.noise),
                             config.surface.selection)
    record = run_iteration(inputs, controller, mem_prev, mem_new)
    assert record.status == "complete", record.diverged_reason
    return record


def _bounce(short_config, damping, leaves=True):
    """A free bounce off the wall from 10 mm in front of it, logged at every control sample (0.25 s); ``leaves``:
    the robot must have left the wall before the end."""
    config = short_config(**QUIET, **{"reference.duration": 0.25, "simulation.log_every": 1,
                                      "simulation.initial_position": [0.35, 0.39], "wall.damping": damping})
    robot = FiveBar(config.plant.links())
    theta0 = robot.inverse_kinematics(config.simulation.initial_position)
    push = robot.jacobian(theta0).T @ np.array([0.0, PUSH_FORCE])
    record = _run(config, push_law, (*push, *([0.0] * 7)))
    energy = np.array([robot.kinetic_energy(q, dq) for q, dq in zip(record.log["joint_angle"],
                                                                    record.log["joint_rate"])])
    pen = record.log["position"][:, 1] - config.wall.position
    contact = np.flatnonzero(pen > 0)
    assert contact.size > 100 and contact[0] > PUSH_SAMPLES, "the bounce must start after the push"
    assert not leaves or contact[-1] < pen.size - 50, "the robot must leave the wall before the horizon"
    return config, record, energy, contact


def test_an_undamped_wall_gives_back_every_joule(short_config):
    """D_e = 0: the kinetic energy after the bounce is the one before (the spring is conservative). RK4 at
    h = 0.1 ms on the contact mode (omega = sqrt(K_e / m) ~ 50 rad/s) errs by ~(omega h)^4 ~ 1e-9 relative per
    radian, and the two instants where the force's slope jumps (entering, leaving) by ~(omega h)^3 ~ 1e-7
    each: 1e-6 relative is above both and five orders below the damped wall's loss below."""
    _config, _record, energy, contact = _bounce(short_config, 0.0)
    before, after = energy[contact[0] - 1], energy[contact[-1] + 1]
    assert after == pytest.approx(before, rel=1e-6), f"the undamped wall changed the energy: {before} -> {after}"


def test_a_damped_wall_dissipates_what_its_damper_works(short_config):
    """D_e = 20 N s/m (about half the critical damping, docs/model.md#wall): the robot leaves with less kinetic
    energy, and the loss is the wall's work on the robot, -w F_n dy/dt integrated over the contact (the log at
    every sample, the trapezoid rule). A Kelvin-Voigt wall's force jumps at impact (to D_e times the impact
    speed) and its power jumps again where the clamp takes over; at each jump the trapezoid rule, and RK4's
    step across it, err by up to about h/2 times the jump: two jumps, two errors each, h max|power| in all.
    The smooth part's error (~(h / 60 ms)^2 of the work) is far below."""
    config, record, energy, contact = _bounce(short_config, 20.0)
    before, after = energy[contact[0] - 1], energy[contact[-1] + 1]
    assert after < 0.9 * before, f"the damped wall did not dissipate: {before} -> {after}"
    span = slice(contact[0] - 1, contact[-1] + 2)
    power = -config.wall.sign * record.log["contact_force"][span, 1] * record.log["velocity"][span, 1]
    work = np.trapezoid(power, dx=config.simulation.sample_time)
    bound = config.simulation.sample_time * np.abs(power).max()
    assert abs((after - before) - work) <= bound, f"the energy lost, {before - after} J, is not the wall's work"
    assert np.all(record.log["contact_force"][:, 0] == 0.0), "a frictionless wall gave an in-plane force"


def test_the_wall_never_pulls(short_config):
    """A damper of 200 N s/m (about five times critical): on the way out the damper's term exceeds the spring's
    while the robot is still in the wall, and the clamp holds the force at 0 there instead of pulling."""
    config, record, _energy, contact = _bounce(short_config, 200.0, leaves=False)
    force = record.log["contact_force"][:, 1]
    assert np.all(force >= 0.0), f"the wall pulled: {force.min()} N"
    leaving = record.log["velocity"][contact, 1] < 0
    assert np.any(force[contact][leaving] == 0.0), "the clamp never acted, the case tests nothing"
    spring = config.wall.stiffness * (record.log["position"][contact, 1] - config.wall.position)
    kelvin_voigt = spring + config.wall.damping * record.log["velocity"][contact, 1]
    np.testing.assert_allclose(force[contact], np.maximum(kelvin_voigt, 0.0), rtol=1e-12, atol=1e-12,
                               err_msg="the logged force is not max(0, K_e pen + D_e dpen/dt)")


def _slide_config(short_config, **overrides):
    return short_config(**QUIET, **{"reference.duration": 0.05, "wall.damping": 20.0, "wall.friction": 0.3,
                                    **overrides})


def test_press_and_slide_against_solve_ivp(short_config):
    """A joint PD pressing 10 mm into the wall and 20 mm along it, on the damped wall with friction (mu = 0.3),
    against scipy's DOP853 on an independent right-hand side (the forces written out here from the law of
    docs/model.md#wall, through the plant's public forward dynamics). Both integrate the same zero-order hold;
    RK4 at h = 0.1 ms on the fastest mode here, the friction's smoothing (slope mu F_n / v_eps <= 0.3 x 10 N /
    0.01 m/s = 300 N s/m on ~0.6 kg, 500 1/s, h lambda = 0.05) errs by ~(h lambda)^5 ~ 3e-7 of the step's
    velocity change per step: 1e-8 rad and 1e-6 rad/s, as for the frictionless wall (tests/test_simulate.py)."""
    config = _slide_config(short_config)
    robot = FiveBar(config.plant.links())
    target = robot.inverse_kinematics((0.33, 0.41))
    record = _run(config, pd_law, (*target, *([0.0] * 7)))
    wall = config.wall

    def rhs(t, x, tau):
        theta, dtheta = x[:2], x[2:]
        y = robot.forward_kinematics(theta)[1]
        v = robot.jacobian(theta) @ dtheta
        pen = y - wall.position
        normal = max(0.0, wall.stiffness * pen + wall.damping * v[1]) if pen > 0 else 0.0
        friction = -wall.friction * normal * math.tanh(abs(v[0]) / wall.friction_velocity) * np.sign(v[0])
        return np.concatenate([dtheta, robot.forward_dynamics(theta, dtheta, tau, (friction, -normal))])

    states = pd_reference(rhs, robot, config, target, _KP, _KD)
    np.testing.assert_allclose(record.log["joint_angle"], states[:, :2], rtol=0, atol=1e-8,
                               err_msg="RK4 on the damped wall with friction departs from the solve_ivp reference")
    np.testing.assert_allclose(record.log["joint_rate"], states[:, 2:], rtol=0, atol=1e-6,
                               err_msg="joint rates depart from the solve_ivp reference")
    assert np.abs(record.log["velocity"][:, 0]).max() > 5 * wall.friction_velocity, "it must slide"


def test_friction_opposes_sliding_with_mu_times_the_normal_force(short_config):
    """Where the tool slides (|v_x| >= 5 v_eps, where tanh is within 1e-4 of 1) the wall's friction on the robot,
    -w F_x, opposes v_x and its size is mu F_n; the sensor does not read it (docs/model.md#wall)."""
    config = _slide_config(short_config)
    robot = FiveBar(config.plant.links())
    record = _run(config, pd_law, (*robot.inverse_kinematics((0.33, 0.41)), *([0.0] * 7)))
    force, velocity = record.log["contact_force"], record.log["velocity"]
    sliding = (np.abs(velocity[:, 0]) >= 5 * config.wall.friction_velocity) & (force[:, 1] > 0)
    assert sliding.sum() > 5, "no sliding sample in contact: the case tests nothing"
    on_robot = -config.wall.sign * force[sliding, 0]
    assert np.all(np.sign(on_robot) == -np.sign(velocity[sliding, 0])), "friction does not oppose the sliding"
    np.testing.assert_allclose(np.abs(on_robot), config.wall.friction * force[sliding, 1], rtol=1e-4,
                               err_msg="the sliding friction is not mu F_n")
    assert np.all(record.log["contact_force_measured"][:, 0] == 0.0), "the (noise-free) sensor read the friction"
    np.testing.assert_array_equal(record.log["contact_force_measured"][:, 1], force[:, 1])


@pytest.mark.parametrize(("setting", "words"), [
    ("wall.damping=-1", "wall.damping must be in [0"),
    ("wall.friction=-0.1", "wall.friction must be in [0"),
    ("wall.friction_velocity=0", "wall.friction_velocity must be in [1e-09"),
    ("wall.friction_velocity=1e-320", "wall.friction_velocity must be in [1e-09"),
    ("wall.damping=inf", "wall.damping must be finite"),
])
def test_bad_wall_values_are_one_line_and_exit_2(setting, words):
    from typer.testing import CliRunner

    from ilcforce.cli.main import app

    result = CliRunner().invoke(app, ["config", "--set", setting])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and words in lines[0], result.output


@pytest.mark.parametrize(("field", "value"), [("damping", -1.0), ("friction", math.nan), ("friction_velocity", 0.0)])
def test_the_wall_checks_its_own_fields(field, value):
    from ilcforce.task import Wall

    with pytest.raises(ValueError, match=f"wall.{field} must be"):
        Wall(**{field: value})


# --- no damper, no friction: the spatial arm's iteration as before the damper existed -------------------------
#: A short run of the spatial arm (C3, its nominal plant at j = 0 and the changed one at j = 1), stored by the
#: code before the damper and friction existed (commit eddc1b3) as tests/data/contact_zero_arm3*.npz: with
#: wall.damping = 0 and wall.friction = 0 (the defaults) every logged number must be the same, bit for bit. As
#: tests/test_reference_run.py explains, NumPy's sin and cos differ in the last bit between hosts with and
#: without AVX-512, which the reference trajectory carries on: one file per kind of host, a run equals one.
#: (The five-bar's bit-for-bit check is tests/test_reference_run.py, unchanged by the damper.)
ARM3 = Path(__file__).parent / "data" / "contact_zero_arm3.npz"
ARM3_REFERENCES = (ARM3, ARM3.with_name("contact_zero_arm3_no_avx512.npz"))
ARM3_ARGS = ("simulate", "-c", str(Path(__file__).resolve().parent.parent / "experiments" / "arm3.toml"), "-m", "c3", "-n", "2", "--set", "reference.duration=0.1",
             "--set", "plant.perturbation.from_iteration=1")


def _arm3_numbers(results: Path, cwd: Path) -> dict[str, np.ndarray]:
    import h5py

    proc = subprocess.run([sys.executable, "-m", "ilcforce", *ARM3_ARGS, "--results", str(results)],
                          capture_output=True, text=True, cwd=cwd, timeout=900)
    assert proc.returncode == 0, proc.stderr
    (found,) = sorted(Path(results).rglob("c3.h5"))
    numbers: dict[str, np.ndarray] = {}
    with h5py.File(found, "r") as handle:
        def visit(name, item):
            if isinstance(item, h5py.Dataset) and "/log/" in f"/{name}" and item.dtype.kind == "f":
                numbers[name] = item[()]
        handle.visititems(visit)
    assert len(numbers) > 20, sorted(numbers)
    return numbers


@pytest.mark.slow  # a fresh process compiles the spatial arm through numba (about 70 s on a fresh clone: a model
# file's arm is not in the ahead-of-time module); tests/test_reference_run.py holds the same contact code bit for
# bit on the five-bar in every run. `make test-slow` runs it.
def test_no_damper_no_friction_is_the_spatial_arms_iteration_as_before(tmp_path):
    numbers = _arm3_numbers(tmp_path / "results", Path(__file__).parent.parent)
    found = {}
    for path in ARM3_REFERENCES:
        reference = np.load(path, allow_pickle=False)
        assert sorted(reference.files) == sorted(numbers), f"{path.name}: other datasets"
        found[path.name] = [k for k in reference.files if not np.array_equal(reference[k], numbers[k], equal_nan=True)]
    assert any(not differ for differ in found.values()), (
        "the spatial arm's run equals no reference: "
        + "; ".join(f"{name}: {len(d)} differ, e.g. {d[:4]}" for name, d in found.items()))


if __name__ == "__main__":  # PYTHONPATH=<tree at eddc1b3> python tests/test_contact_damping.py <target.npz>
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:  # run outside any tree, so that PYTHONPATH decides the code
        probe = subprocess.run([sys.executable, "-c", "import ilcforce; print(ilcforce.__file__)"], cwd=tmp,
                               capture_output=True, text=True, check=True)
        print(f"ilcforce from {probe.stdout.strip()}")
        made = _arm3_numbers(Path(tmp) / "results", Path(tmp))
    np.savez_compressed(sys.argv[1], **made)
    print(f"{len(made)} datasets -> {sys.argv[1]}")


def test_tau_ds_friction_is_the_plants_law():
    """simulate.desired_friction writes, on the whole grid in numpy, the friction ndof.contact.drift applies through
    task.friction_scale: the two forms of one law agree on speeds around v_eps and at rest."""
    from ilcforce.simulate import desired_friction
    from ilcforce.task import REF_FORCE, REF_VELOCITY, Wall, friction_scale, reference_block

    wall = Wall(friction=0.3, friction_velocity=0.01)
    speeds = np.array([0.0, 1e-6, 0.003, 0.01, 0.04, 0.2, -0.05])
    ref = np.zeros((speeds.size, 12))
    reference_block(ref, REF_VELOCITY, 2)[:, 0] = speeds
    reference_block(ref, REF_FORCE, 2)[:, 1] = 7.0
    got = reference_block(desired_friction(wall, ref, 2), REF_FORCE, 2)[:, 0]
    want = [wall.sign * 0.3 * 7.0 * friction_scale(abs(v), 0.01) * v for v in speeds]
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=0.0)
    assert got[0] == 0.0 and np.all(np.sign(got[1:]) == np.sign(speeds[1:]) * wall.sign)
