"""Robots from a model file (docs/model.md#model-file, ``ilcforce.plants.load_model``).

What is checked, and against what:

* The loader library's own functions, on 1,000 random states of each shipped model (the 2R arm and
  the 3-DOF arm, each as MJCF and URDF) and of a generated random 4-link chain (random placements,
  axes, anchors, reference angles, a slide joint, a fixed body between links, a site on a fixed
  tool body): M(q) (mj_fullM), the bias C dq + g (qfrc_bias), the end effector's position, Jacobian
  (mj_jac) and its derivative (mj_jacDot), and inverse dynamics (mj_rne with qacc), to 1e-10
  relative. The regressor: Y a equals inverse dynamics to round-off, and Y does not depend on the
  inertial parameters.
* The closed-form Serial2R (docs/model.md#serial2r): the 2R model files give its inertia, Christoffel
  Coriolis matrix, gravity, kinematics, Jacobian and potential energy to 1e-12.
* Physics: M symmetric positive definite, dM/dt - 2C skew, energy balance along RK4 (with and
  without gravity), the task-space model of eq. (4) on the 3-DOF arm.
* Every way a file can fail gives one line (ModelFileError, a ValueError).
"""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

from ilcforce.plants import chain  # noqa: E402
from ilcforce.plants.model_file import (  # noqa: E402
    ModelFileError,
    _compile,
    check_task_dimension,
    load_model,
    resolve_model,
    shipped_models,
)
from ilcforce.plants.serial2r import Serial2R  # noqa: E402
from ilcforce.plants.serial_arm import SerialArm  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "experiments" / "models"
STATES = 1000
#: the bar against the library: both sides are float64 recursions over the same parameters, so they
#: agree to a few ulp of the largest term (1e-15 to 1e-14 measured); 1e-10 leaves room for ill-scaled
#: models without hiding a wrong term (a wrong sign or a missing product is O(1) relative)
LIBRARY_RTOL = 1e-10
#: the closed-form 2R arm against the file: the same numbers through two exact algorithms
CLOSED_FORM_RTOL = 1e-12
#: Y a against Newton-Euler: the same quantities summed in another order
ROUND_OFF_RTOL = 1e-12


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _quat(rng) -> str:
    v = rng.normal(size=4)
    return " ".join(f"{x:.17g}" for x in v / np.linalg.norm(v))


def _vec(values) -> str:
    return " ".join(f"{x:.17g}" for x in values)


def _inertia(rng, scale) -> str:
    """A physical inertia tensor (the principal moments obey the triangle inequality) in random axes, as
    MJCF's fullinertia "ixx iyy izz ixy ixz iyz"."""
    a, b = rng.uniform(0.3, 1.0, 2) * scale
    c = rng.uniform(abs(a - b) + 0.05 * scale, a + b - 0.05 * scale)
    R = _rotation(rng)
    I = R @ np.diag([a, b, c]) @ R.T
    return _vec([I[0, 0], I[1, 1], I[2, 2], I[0, 1], I[0, 2], I[1, 2]])


def random_chain_mjcf(seed: int) -> str:
    """A random 4-link serial chain: random body placements and orientations, joint anchors off the
    body origin, random unit axes and reference values, link 3 a slide joint, a massive fixed body
    between links 2 and 3, a massive fixed tool body carrying the end-effector site."""
    rng = np.random.default_rng(seed)

    def body(name, joint_type, inner):
        axis = rng.normal(size=3)
        joint = (f'<joint name="j_{name}" type="{joint_type}" axis="{_vec(axis)}" pos="{_vec(rng.uniform(-0.1, 0.1, 3))}" '
                 f'ref="{rng.uniform(-0.5, 0.5):.17g}"/>')
        return (f'<body name="{name}" pos="{_vec(rng.uniform(-0.3, 0.3, 3))}" quat="{_quat(rng)}">{joint}'
                f'<inertial pos="{_vec(rng.uniform(-0.15, 0.15, 3))}" mass="{rng.uniform(0.3, 3.0):.17g}" '
                f'fullinertia="{_inertia(rng, 0.02)}"/>{inner}</body>')

    tool = (f'<body name="tool" pos="{_vec(rng.uniform(-0.2, 0.2, 3))}" quat="{_quat(rng)}">'
            f'<inertial pos="{_vec(rng.uniform(-0.05, 0.05, 3))}" mass="0.4" fullinertia="{_inertia(rng, 0.002)}"/>'
            f'<site name="tcp" pos="{_vec(rng.uniform(-0.1, 0.1, 3))}"/></body>')
    fixed = (f'<body name="bracket" pos="{_vec(rng.uniform(-0.2, 0.2, 3))}" quat="{_quat(rng)}">'
             f'<inertial pos="{_vec(rng.uniform(-0.05, 0.05, 3))}" mass="0.8" fullinertia="{_inertia(rng, 0.004)}"/>'
             "{inner}</body>")
    inner = body("l4", "hinge", tool)
    inner = body("l3", "slide", inner)
    inner = body("l2", "hinge", fixed.format(inner=inner))
    inner = body("l1", "hinge", inner)
    return f'<mujoco model="random4"><worldbody>{inner}</worldbody></mujoco>'


CASES = {  # name -> (file, end effector)
    "serial2r.xml": ("serial2r.xml", "tool"),
    "serial2r.urdf": ("serial2r.urdf", "tool"),
    "arm3.xml": ("arm3.xml", "tool"),
    "arm3.urdf": ("arm3.urdf", "tool"),
    "random4": (None, "tcp"),
}


@pytest.fixture(scope="module")
def random_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("chain") / "random4.xml"
    path.write_text(random_chain_mjcf(37), encoding="utf-8")
    return path


def _case(name, random_file):
    file, ee = CASES[name]
    path = random_file if file is None else MODELS / file
    return path, ee, load_model(path, ee)


class Library:
    """MuJoCo's own answers on the model the loader compiled (the same file, the same compile options)."""

    def __init__(self, path: Path, ee: str, gravity) -> None:
        self.m = _compile(path)
        self.m.opt.gravity[:] = gravity
        self.d = mujoco.MjData(self.m)
        site = mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_SITE, ee)
        self.site = site if site >= 0 else None
        self.body = int(self.m.site_bodyid[site]) if site >= 0 else mujoco.mj_name2id(self.m, mujoco.mjtObj.mjOBJ_BODY, ee)

    def at(self, q, dq, ddq) -> dict[str, np.ndarray]:
        m, d = self.m, self.d
        d.qpos[:], d.qvel[:] = q, dq
        mujoco.mj_forward(m, d)
        nv = m.nv
        M = np.zeros((nv, nv))
        mujoco.mj_fullM(m, d, M)
        point = d.site_xpos[self.site].copy() if self.site is not None else d.xpos[self.body].copy()
        J = np.zeros((3, nv))
        mujoco.mj_jac(m, d, J, None, point, self.body)
        dJ = np.zeros((3, nv))
        mujoco.mj_jacDot(m, d, dJ, None, point, self.body)
        d.qacc[:] = ddq
        tau = np.zeros(nv)
        mujoco.mj_rne(m, d, 1, tau)  # M qacc + C dq + g: no joint-limit or passive forces (mj_inverse adds them)
        return {"M": M, "bias": d.qfrc_bias.copy(), "P": point, "J": J, "dJ": dJ, "tau": tau}


def _states(n: int, count: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        yield rng.uniform(-math.pi, math.pi, n), rng.uniform(-3.0, 3.0, n), rng.uniform(-10.0, 10.0, n)


def _relative(ours, theirs) -> float:
    scale = np.linalg.norm(theirs)
    return float(np.linalg.norm(np.asarray(ours) - theirs) / scale) if scale else float(np.linalg.norm(ours))


#: the largest relative errors seen against the library, per model and quantity (printed by -s)
WORST: dict[str, dict[str, float]] = {}


@pytest.mark.parametrize("name", list(CASES))
def test_dynamics_equal_the_librarys_on_random_states(name, random_file):
    path, ee, arm = _case(name, random_file)
    library = Library(path, ee, arm.gravity_vector)
    worst: dict[str, float] = {}
    a = arm.inertial_parameters().ravel()
    for q, dq, ddq in _states(arm.n, STATES, seed=len(name)):
        ref = library.at(q, dq, ddq)
        tau = arm.inverse_dynamics(q, dq, ddq)
        ours = {"M": arm.joint_inertia(q), "bias": arm.bias(q, dq), "P": arm.forward_kinematics(q),
                "J": arm.jacobian(q), "dJ": arm.jacobian_derivative(q, dq), "tau": tau,
                "C dq + g": arm.joint_coriolis(q, dq) @ dq + arm.gravity(q)}
        for key, value in ours.items():
            worst[key] = max(worst.get(key, 0.0), _relative(value, ref["bias" if key == "C dq + g" else key]))
        worst["Y a"] = max(worst.get("Y a", 0.0), _relative(arm.regressor(q, dq, ddq) @ a, tau))
    WORST[name] = worst
    print(name, {k: f"{v:.1e}" for k, v in worst.items()})
    bad = {k: v for k, v in worst.items() if v > (ROUND_OFF_RTOL if k == "Y a" else LIBRARY_RTOL)}
    assert not bad, f"{name}: relative errors against MuJoCo over the bar: {bad}"


def test_the_regressor_depends_on_the_motion_only(random_file):
    """Y(q, dq, ddq) of an arm with other inertial parameters (same kinematics) is the same matrix, and
    Y a' is that arm's inverse dynamics: the regressor is linear in each link's ten parameters."""
    arm = load_model(random_file, "tcp")
    p = arm.packed.copy()
    rng = np.random.default_rng(5)
    for i in range(arm.n):
        b = chain.HEADER + chain.LINK * i
        p[b + 20] *= rng.uniform(0.5, 2.0)  # mass
        p[b + 21:b + 24] += rng.uniform(-0.05, 0.05, 3)  # centre of mass
        p[b + 24:b + 33] *= rng.uniform(0.5, 2.0)  # inertia (a positive multiple stays physical)
    other = SerialArm(p)
    assert not np.allclose(other.inertial_parameters(), arm.inertial_parameters())
    for q, dq, ddq in _states(arm.n, 50, seed=9):
        Y = arm.regressor(q, dq, ddq)
        assert Y.shape == (arm.n, 10 * arm.n)
        np.testing.assert_array_equal(other.regressor(q, dq, ddq), Y)
        tau = other.inverse_dynamics(q, dq, ddq)
        assert _relative(Y @ other.inertial_parameters().ravel(), tau) < ROUND_OFF_RTOL


# --- the 2R model files are the closed-form Serial2R --------------------------------------------------

@pytest.mark.parametrize("file", ["serial2r.xml", "serial2r.urdf"])
def test_the_2r_model_file_is_serial2r(file):
    """The files' plane (x, z) is Serial2R's (x, y), their joints turn about -y: the same angles, and
    rows x and z of P and J are Serial2R's; y stays 0."""
    arm, closed = load_model(MODELS / file, "tool"), Serial2R()
    rng = np.random.default_rng(2)
    worst = {}
    for _ in range(STATES):
        q = np.array([rng.uniform(-math.pi, math.pi), rng.uniform(0.05, math.pi - 0.05)])  # Serial2R's working mode
        dq, ddq = rng.uniform(-3.0, 3.0, 2), rng.uniform(-10.0, 10.0, 2)
        pairs = {
            "joint_inertia": (arm.joint_inertia(q), closed.joint_inertia(q)),
            "joint_coriolis": (arm.joint_coriolis(q, dq), closed.joint_coriolis(q, dq)),
            # Newton-Euler without gravity, not bias - gravity (which loses digits where C dq << g)
            "coriolis dq": (chain.inverse_dynamics(arm.packed, q, dq, np.zeros(2), False),
                            closed.joint_coriolis(q, dq) @ dq),
            "gravity": (arm.gravity(q), closed.gravity(q)),
            "forward_kinematics": (arm.forward_kinematics(q)[[0, 2]], closed.forward_kinematics(q)),
            "jacobian": (arm.jacobian(q)[[0, 2]], closed.jacobian(q)),
            "jacobian_derivative": (arm.jacobian_derivative(q, dq)[[0, 2]], closed.jacobian_derivative(q, dq)),
            "inverse_dynamics": (arm.inverse_dynamics(q, dq, ddq), closed.inverse_dynamics(q, dq, ddq)),
            "potential_energy": (arm.potential_energy(q), closed.potential_energy(q)),
        }
        for key, (ours, theirs) in pairs.items():
            worst[key] = max(worst.get(key, 0.0), _relative(ours, theirs))
        assert arm.forward_kinematics(q)[1] == 0.0 and not arm.jacobian(q)[1].any()
    WORST[f"{file} vs Serial2R"] = worst
    print(file, "vs Serial2R", {k: f"{v:.1e}" for k, v in worst.items()})
    bad = {k: v for k, v in worst.items() if v > CLOSED_FORM_RTOL}
    assert not bad, f"{file} differs from Serial2R: {bad}"


def test_the_two_formats_describe_the_same_arms():
    for stem in ("serial2r", "arm3"):
        mjcf, urdf = load_model(MODELS / f"{stem}.xml", "tool"), load_model(MODELS / f"{stem}.urdf", "tool")
        for q, dq, ddq in _states(mjcf.n, 20, seed=3):
            np.testing.assert_allclose(urdf.inverse_dynamics(q, dq, ddq), mjcf.inverse_dynamics(q, dq, ddq),
                                       rtol=0, atol=1e-12 * np.linalg.norm(mjcf.inverse_dynamics(q, dq, ddq)))
            np.testing.assert_allclose(urdf.forward_kinematics(q), mjcf.forward_kinematics(q), rtol=0, atol=1e-15)


# --- physics ----------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["arm3.xml", "random4"])
def test_inertia_spd_and_coriolis_skew(name, random_file):
    _, _, arm = _case(name, random_file)
    h = 1e-6
    for q, dq, _ in _states(arm.n, 100, seed=11):
        M = arm.joint_inertia(q)
        assert np.array_equal(M, M.T)
        ev = np.linalg.eigvalsh(M)
        assert ev.min() > 1e-9 * ev.max(), f"M not positive definite at {q}: {ev}"
        # dM/dt by central differences (truncation ~h^2, rounding ~eps/h ~ 2e-10 relative): 1e-7 of the scale
        dM = (arm.joint_inertia(q + h * dq) - arm.joint_inertia(q - h * dq)) / (2 * h)
        C = arm.joint_coriolis(q, dq)
        skew = dM - 2.0 * C
        np.testing.assert_allclose(skew + skew.T, 0.0, atol=1e-7 * (np.linalg.norm(dM) + 2 * np.linalg.norm(C)))
        np.testing.assert_allclose(C @ dq + arm.gravity(q), arm.bias(q, dq), rtol=0,
                                   atol=1e-12 * np.linalg.norm(arm.bias(q, dq)))
        # gravity is the gradient of the potential energy
        G_fd = np.array([(arm.potential_energy(q + h * e) - arm.potential_energy(q - h * e)) / (2 * h)
                         for e in np.eye(arm.n)])
        np.testing.assert_allclose(arm.gravity(q), G_fd, rtol=0, atol=1e-7 * max(1.0, np.linalg.norm(G_fd)))


def _rk4(arm, q0, dq0, tau, step, n):
    def f(s):
        return np.concatenate([s[arm.n:], arm.forward_dynamics(s[:arm.n], s[arm.n:], tau)])

    s = np.concatenate([q0, dq0])
    out = [s]
    for _ in range(n):
        k1 = f(s)
        k2 = f(s + 0.5 * step * k1)
        k3 = f(s + 0.5 * step * k2)
        k4 = f(s + step * k3)
        s = s + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        out.append(s)
    return np.array(out)


def _energy_error(arm, tau, step, duration=0.2):
    """(max |T + V - W - E(0)|, energy exchanged) along RK4, W the work of the constant torque ``tau``."""
    q0, dq0 = np.array([0.4, 0.6, 1.1, -0.3][:arm.n]), np.array([0.8, -0.5, 1.2, 0.7][:arm.n])
    states = _rk4(arm, q0, dq0, tau, step, round(duration / step))
    V = np.array([arm.potential_energy(s[:arm.n]) for s in states])
    W = np.array([tau @ (s[:arm.n] - q0) for s in states])
    T = np.array([arm.kinetic_energy(s[:arm.n], s[arm.n:]) for s in states])
    E = T + V - W
    return float(np.max(np.abs(E - E[0]))), float(np.max(np.abs(T - T[0])) + np.max(np.abs(V - V[0])) + np.max(np.abs(W)))


@pytest.mark.parametrize("gravity", [(0.0, 0.0, 0.0), (0.0, 0.0, -9.81)], ids=["no-gravity", "gravity"])
@pytest.mark.parametrize("name", ["arm3.urdf", "random4"])
def test_energy_balance(name, gravity, random_file):
    """dT/dt = dq . (tau - g(q)): T + V - W is conserved along the motion under a constant torque; the
    error left is RK4's, which falls ~16x when the step halves (a wrong term would not shrink)."""
    path, ee, _ = _case(name, random_file)
    arm = load_model(path, ee, gravity=gravity)
    tau = np.array([1.5, -2.0, 0.8, 0.5][:arm.n])
    (coarse, _), (fine, exchanged) = _energy_error(arm, tau, 2e-3), _energy_error(arm, tau, 1e-3)
    assert exchanged > 0.01, f"only {exchanged:.3g} J exchanged: the test would see nothing"
    assert coarse / fine > 11, f"energy error ratio {coarse / fine:.3g} (coarse {coarse:.3g}, fine {fine:.3g} J)"
    assert fine < 1e-7 * exchanged, f"energy error {fine:.3g} J of {exchanged:.3g} J exchanged"


def test_forward_dynamics_inverts_inverse_dynamics_with_a_tip_force(random_file):
    arm = load_model(random_file, "tcp")
    f = np.array([3.0, -1.0, 2.0])
    for q, dq, ddq in _states(arm.n, 20, seed=4):
        tau = arm.inverse_dynamics(q, dq, ddq, f)
        np.testing.assert_allclose(tau, arm.inverse_dynamics(q, dq, ddq) - arm.jacobian(q).T @ f, rtol=1e-13, atol=1e-12)
        cond = np.linalg.cond(arm.joint_inertia(q))
        np.testing.assert_allclose(arm.forward_dynamics(q, dq, tau, f), ddq, rtol=0,
                                   atol=1e-14 * cond * np.linalg.norm(ddq) * 10)


def test_task_space_model_of_the_3dof_arm():
    """eq. (4) on the 3-DOF arm away from singularities: D = J^-T Dq J^-1 symmetric positive definite,
    dD/dt - 2C skew, G = J^-T G_q; an arm with n != 3 has no square task model."""
    arm = load_model(MODELS / "arm3.xml", "tool")
    h = 1e-6
    for q in (np.array([0.3, 0.5, 1.2]), np.array([-1.0, 0.2, 0.8]), np.array([2.0, -0.4, 1.9])):
        J = arm.jacobian(q)
        assert np.linalg.cond(J) < 50
        dq = np.array([0.7, -0.4, 0.9])
        D = arm.task_inertia(q)
        np.testing.assert_allclose(D, D.T, rtol=0, atol=1e-12 * np.linalg.norm(D))
        assert np.linalg.eigvalsh(D).min() > 0
        dD = (arm.task_inertia(q + h * dq) - arm.task_inertia(q - h * dq)) / (2 * h)
        C = arm.task_coriolis(q, dq)
        skew = dD - 2 * C
        np.testing.assert_allclose(skew + skew.T, 0.0, atol=1e-6 * (np.linalg.norm(dD) + 2 * np.linalg.norm(C)))
        np.testing.assert_allclose(J.T @ arm.task_gravity(q), arm.gravity(q), rtol=0, atol=1e-12 * np.linalg.norm(arm.gravity(q)))
        # the task-space equation of motion: D ddP + C dP + G = J^-T (tau - ...) at ddq from tau
        tau = np.array([2.0, 5.0, -1.0])
        ddq = arm.forward_dynamics(q, dq, tau)
        ddP = J @ ddq + arm.jacobian_derivative(q, dq) @ dq
        np.testing.assert_allclose(D @ ddP + C @ (J @ dq) + arm.task_gravity(q), np.linalg.solve(J.T, tau), rtol=1e-9)
    with pytest.raises(ValueError, match="3"):
        load_model(MODELS / "serial2r.xml", "tool").task_inertia([0.3, 1.0])


# --- errors: one line each ----------------------------------------------------------------------------

MJCF_BODY = '<body name="{name}" pos="0 0 0.1"><joint name="j{name}" {joint}/><inertial pos="0 0 0.05" mass="1" diaginertia="0.01 0.01 0.01"/>{inner}</body>'


def _mjcf(worldbody: str, extra: str = "") -> str:
    return f"<mujoco><worldbody>{worldbody}</worldbody>{extra}</mujoco>"


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _one_line_error(path, ee="tool", match=""):
    with pytest.raises(ModelFileError) as caught:
        load_model(path, ee)
    message = str(caught.value)
    assert "\n" not in message and message.strip() == message, repr(message)
    assert isinstance(caught.value, ValueError)
    assert re.search(match, message), message
    return message


def test_a_missing_or_unreadable_file(tmp_path):
    _one_line_error(tmp_path / "nowhere.urdf", match=r"nowhere\.urdf: no such model file")
    _one_line_error(tmp_path, match="is a directory")
    locked = _write(tmp_path, "locked.xml", _mjcf(""))
    locked.chmod(0)
    try:
        if os.access(locked, os.R_OK):  # root reads it anyway
            pytest.skip("running as a user who can read a file of mode 000")
        _one_line_error(locked, match="cannot be read")
    finally:
        locked.chmod(0o600)


def test_a_file_mujoco_cannot_parse(tmp_path):
    # read by expat first (model_refs.py: what a file names is checked before MuJoCo opens it)
    _one_line_error(_write(tmp_path, "broken.xml", "<mujoco><worldbody>"), match=r"not well-formed XML \(no element found")
    _one_line_error(_write(tmp_path, "odd.xml", "<mujoco><wrong/></mujoco>"), match="MuJoCo cannot read it: .*unrecognized element")
    _one_line_error(_write(tmp_path, "mesh.xml", _mjcf('<body><joint/><geom type="mesh" mesh="m"/></body>',
                                                      '<asset><mesh name="m" file="missing.stl"/></asset>')),
                    match="MuJoCo cannot read it")


def test_a_closed_chain(tmp_path):
    inner = MJCF_BODY.format(name="b", joint='type="hinge" axis="0 1 0"', inner='<site name="tool"/>')
    text = _mjcf(MJCF_BODY.format(name="a", joint='type="hinge" axis="0 1 0"', inner=inner),
                 '<equality><connect body1="b" body2="world" anchor="0 0 0"/></equality>')
    _one_line_error(_write(tmp_path, "closed.xml", text), match="equality constraint.*closed chain")


def test_a_floating_base_or_a_ball_joint(tmp_path):
    text = _mjcf(MJCF_BODY.format(name="a", joint='type="free"', inner='<site name="tool"/>'))
    _one_line_error(_write(tmp_path, "free.xml", text), match="free joint.*floating base")
    text = _mjcf(MJCF_BODY.format(name="a", joint='type="ball"', inner='<site name="tool"/>'))
    _one_line_error(_write(tmp_path, "ball.xml", text), match="ball joint")
    urdf = ('<robot name="r"><link name="base"/><link name="l"><inertial><mass value="1"/>'
            '<inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/></inertial></link>'
            '<joint name="float" type="floating"><parent link="base"/><child link="l"/></joint></robot>')
    _one_line_error(_write(tmp_path, "float.urdf", urdf), ee="l", match="free joint|floating")


def test_a_branching_tree(tmp_path):
    hinge = 'type="hinge" axis="0 1 0"'
    fingers = MJCF_BODY.format(name="left", joint=hinge, inner="") + MJCF_BODY.format(name="right", joint=hinge, inner="")
    text = _mjcf(MJCF_BODY.format(name="palm", joint=hinge, inner=fingers))
    _one_line_error(_write(tmp_path, "hand.xml", text), ee="left", match="'palm' carries both 'left' and 'right'.*not a serial chain")
    two = MJCF_BODY.format(name="a", joint=hinge, inner="") + MJCF_BODY.format(name="b", joint=hinge, inner="")
    _one_line_error(_write(tmp_path, "two.xml", _mjcf(two)), ee="a", match="the world carries both")


def test_two_joints_in_one_body_and_armature(tmp_path):
    text = _mjcf('<body name="a"><joint name="x" type="hinge" axis="1 0 0"/><joint name="y" type="hinge" axis="0 1 0"/>'
                 '<inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/><site name="tool"/></body>')
    _one_line_error(_write(tmp_path, "two.xml", text), match="'a' has 2 joints")
    text = _mjcf(MJCF_BODY.format(name="a", joint='type="hinge" armature="0.1"', inner='<site name="tool"/>'))
    _one_line_error(_write(tmp_path, "armature.xml", text), match="armature")


def test_an_end_effector_that_does_not_exist():
    message = _one_line_error(MODELS / "arm3.urdf", ee="gripper", match="no end effector 'gripper'")
    assert "links (bodies): base_link, turret, upper_arm, forearm, tool" in message
    message = _one_line_error(MODELS / "serial2r.xml", ee="tcp", match="no end effector 'tcp'")
    assert "sites: tool" in message
    _one_line_error(MODELS / "arm3.urdf", ee="base_link", match="fixed to the world")


def test_a_joint_count_other_than_the_task_dimension():
    arm = load_model(MODELS / "arm3.xml", "tool")
    check_task_dimension(arm, 3)
    with pytest.raises(ModelFileError, match=r"the robot has 3 joints but the task has 2 dimensions") as caught:
        check_task_dimension(arm, 2)
    assert "\n" not in str(caught.value)


def test_a_bad_gravity_vector():
    with pytest.raises(ModelFileError, match="gravity must be three finite numbers"):
        load_model(MODELS / "arm3.xml", "tool", gravity=(0.0, -9.81))


# --- loading -----------------------------------------------------------------------------------------

def test_a_urdf_tool_link_survives_where_mujoco_would_fuse_it():
    """MuJoCo's own URDF import merges a link on a fixed joint into its parent (the tool's name is
    gone); the loader keeps it, and its mass joins the forearm's link in the dynamics."""
    fused = mujoco.MjModel.from_xml_path(str(MODELS / "arm3.urdf"))
    assert mujoco.mj_name2id(fused, mujoco.mjtObj.mjOBJ_BODY, "tool") < 0
    arm = load_model(MODELS / "arm3.urdf", "tool")
    assert arm.link_names == ("turret", "upper_arm", "forearm") and arm.joint_names == ("base_yaw", "shoulder", "elbow")
    # the tool's 0.25 kg is in the last link: 1.1 + 0.25 kg
    assert arm.inertial_parameters()[2, 0] == pytest.approx(1.35, rel=1e-15)
    np.testing.assert_allclose(arm.forward_kinematics([0.0, 0.0, 0.0]), [0.69, 0.0, 0.30], rtol=0, atol=1e-15)


def test_shipped_models_are_found_by_name(tmp_path, monkeypatch):
    assert {"arm3.xml", "arm3.urdf", "serial2r.xml", "serial2r.urdf"} <= set(shipped_models())
    monkeypatch.chdir(tmp_path)
    assert resolve_model("arm3.urdf") == MODELS / "arm3.urdf"
    assert load_model("arm3.urdf", "tool").n == 3
    (tmp_path / "arm3.urdf").write_text("<robot/>")  # a file of the user's own wins
    assert resolve_model("arm3.urdf") == Path("arm3.urdf")


def test_only_reading_a_file_imports_mujoco():
    """The five-bar's simulation and ilcforce's names never import MuJoCo; load_model does
    (tests/test_imports.py pins the CLI's help and version)."""
    code = ("import sys\nimport ilcforce, ilcforce.plants\nfrom ilcforce.plants import SerialArm, ModelFileError\n"
            "from ilcforce.config_load import load_config\nfrom ilcforce.experiment import simulate_iterations\n"
            "cfg = load_config(None, {'experiment.iterations': 1, 'reference.duration': 0.05})\n"
            "next(simulate_iterations(cfg, 'c3'))\n"
            "print('BEFORE', 'mujoco' in sys.modules)\n"
            "ilcforce.load_model('arm3.xml', 'tool')\nprint('AFTER', 'mujoco' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "BEFORE False" in done.stdout and "AFTER True" in done.stdout


def test_the_docs_api_example_runs(tmp_path):
    text = (ROOT / "docs" / "api.md").read_text(encoding="utf-8")
    match = re.search(r"<!-- model-file-example: run by tests/test_model_file.py -->\s*```python\n(.*?)```", text, re.S)
    assert match, "docs/api.md has no marked model-file example"
    done = subprocess.run([sys.executable, "-c", match.group(1)], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "SerialArm(3 joints" in done.stdout
