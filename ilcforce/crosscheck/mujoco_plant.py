"""The true plant of the cross-check (docs/crosscheck.md): a robot of ilcforce's simulated by MuJoCo, pressing on
a plane through MuJoCo's own soft contact.

The robot comes from its model file as MuJoCo reads it (its own inertias, kinematics and integrator): the plant's
parameters say which file and how (their ``mujoco_model``, :class:`ilcforce.plants.model_file.MujocoModel`; a
closed-form arm gives its shipped file with its parameters set). Bodies fixed to a moving link are fused into it (MuJoCo's
``fusestatic``), so that a perturbation scales the link as ilcforce does (``<link>.mass``: the fused link's
mass, its centre of mass and centroidal inertia kept; ``<link>.inertia``: the centroidal inertia).

The wall is a MuJoCo plane whose outward normal points at the robot's side, set back by the radius r of a
small sphere at the end effector, so the contact's penetration is the wall's, w (n . P - y_e) (ilcforce.task).
MuJoCo's soft constraint (its documentation's "solver parameters"): with a flat impedance d (solimp
[d, d, ...]) and solref [-s, -b] given directly as stiffness s and damping b (the negative form), the normal
force in contact is

    f = (s r + b v) / ((1 - d) A) + d / (1 - d) (1 / A) a1,

r the penetration, v its rate, A MuJoCo's constant approximation of the contact's inverse effective mass
(from the model at qpos0; MuJoCo regularises the contact with R = (1 - d) / d A) and a1 the contact point's
normal acceleration. So s = K_e (1 - d) A and b = c (1 - d) A give a spring K_e (N/m) and a damper c (N s/m) plus
an added mass d / (1 - d) / A on the contact: with the default d = 1e-4 it is 0.01 % of the arm's effective mass. c is stated by a
damping ratio zeta of that effective mass: c = 2 zeta sqrt(K_e / A). :func:`contact_gains` reads A from a
contact MuJoCo makes, so each true plant (a perturbed one has another A) gets K_e exactly.

MuJoCo is imported inside the functions only (a run of ilcforce that does not cross-check never loads it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ContactSettings", "MujocoArm", "build_arm", "simulates"]

#: the end-effector sphere's radius, m: small against the path (the wall's offset absorbs it exactly)
TIP_RADIUS = 1e-3
#: the names the cross-check gives what it adds to a model
SITE, TIP, WALL = "crosscheck_tool", "crosscheck_tip", "crosscheck_wall"


@dataclass(frozen=True)
class ContactSettings:
    """MuJoCo's side of the cross-check (docs/crosscheck.md#contact)."""

    damping_ratio: float = 0.0  # zeta of the wall's damper against the contact's effective mass (0: ilcforce's undamped spring)
    impedance: float = 1e-4  # d of a flat solimp (MuJoCo's least, mjMINIMP): the contact's added mass is d / (1 - d) of its effective mass
    integrator: str = "RK4"  # MuJoCo's integrator (mjtIntegrator's name without mjINT_): RK4, Euler, implicitfast
    steps_per_sample: int = 1  # MuJoCo steps per control sample (timestep = Ts / this)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.damping_ratio) and self.damping_ratio >= 0):
            raise ValueError(f"the damping ratio must be finite and >= 0, got {self.damping_ratio!r}")
        if not (1e-4 <= self.impedance <= 0.9):  # MuJoCo's mjMINIMP; above 0.9 the added mass is 9x
            raise ValueError(f"the impedance d must be in [1e-4, 0.9], got {self.impedance!r}")
        if self.integrator.upper() not in ("RK4", "EULER", "IMPLICIT", "IMPLICITFAST"):
            raise ValueError(f"the integrator must be one of RK4, Euler, implicit, implicitfast; got {self.integrator!r}")
        if not (isinstance(self.steps_per_sample, int) and self.steps_per_sample >= 1):
            raise ValueError(f"MuJoCo steps per control sample must be an integer >= 1, got {self.steps_per_sample!r}")


def simulates(params) -> bool:
    """Whether the plant of ``params`` says how MuJoCo simulates it (its ``mujoco_model``)."""
    return callable(getattr(params, "mujoco_model", None))


class MujocoArm:
    """One true plant in MuJoCo: ``model``, ``data``, the end-effector site, the task frame W (n x 3, world to
    task: the wall's frame R times the task axes) and the contact's stiffness and damping."""

    def __init__(self, model, data, site: int, tip_geom: int, W: np.ndarray, sign: float, force_axis: int) -> None:
        self.model, self.data = model, data
        self.site, self.tip_geom = site, tip_geom
        self.W = W
        self.sign = sign
        self.force_axis = force_axis
        self.contact: dict = {}
        self.n = W.shape[0]
        self._jacp = np.zeros((3, model.nv))
        self._wrench = np.zeros(6)

    def set_state(self, q, dq) -> None:
        import mujoco

        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:] = q
        self.data.qvel[:] = dq
        mujoco.mj_forward(self.model, self.data)

    def forward(self) -> None:
        """MuJoCo's forward dynamics at the current state with the inputs last applied (the contact force)."""
        import mujoco

        mujoco.mj_forward(self.model, self.data)

    def position(self) -> np.ndarray:
        """X = W P, the end effector in the task frame (n,), m."""
        return self.W @ self.data.site_xpos[self.site]

    def task_jacobian(self) -> np.ndarray:
        """J_X = W J_P (n x n) at the current state (MuJoCo's site Jacobian)."""
        import mujoco

        mujoco.mj_jacSite(self.model, self.data, self._jacp, None, self.site)
        return self.W @ self._jacp

    def contact_force(self) -> np.ndarray:
        """The force the end effector applies to the wall in the task frame, ilcforce's sign (n,), N:
        w W f_applied, so its force axis holds F >= 0 (ilcforce.task); MuJoCo's frictionless contact
        gives no in-plane part."""
        import mujoco

        applied = np.zeros(3)
        d = self.data
        for i in range(d.ncon):
            c = d.contact[i]
            if c.geom1 != self.tip_geom and c.geom2 != self.tip_geom:
                continue
            mujoco.mj_contactForce(self.model, d, i, self._wrench)
            # the contact frame's first row is its normal, pointing from geom1 to geom2
            on_geom2 = c.frame[:3] * self._wrench[0]
            applied += on_geom2 if c.geom2 != self.tip_geom else -on_geom2  # on the wall = -(on the tip)
        return self.sign * (self.W @ applied)

    def step(self, joint_force: np.ndarray, steps: int) -> None:
        """Hold the generalised force ``joint_force`` (n,) (the torque and the disturbance's) for ``steps``
        MuJoCo steps."""
        import mujoco

        self.data.qfrc_applied[:] = joint_force
        for _ in range(steps):
            mujoco.mj_step(self.model, self.data)


def contact_gains(model, data, geoms: tuple[int, int], settings: ContactSettings, stiffness: float,
                  q_probe) -> dict:
    """solref and solimp for a wall of ``stiffness`` K_e (N/m) and the settings' damping ratio: MuJoCo makes a
    contact at the pose ``q_probe`` (pushed into the wall) and reports A (``efc_diagApprox``); returns
    {"solref", "solimp", "A", "damping"} and sets them on both geoms."""
    import mujoco

    d = settings.impedance
    solimp = np.array([d, d, 0.001, 0.5, 2.0])
    for g in geoms:
        model.geom_solimp[g] = solimp
        model.geom_solref[g] = [-1.0, -0.0]
    mujoco.mj_resetData(model, data)
    data.qpos[:] = q_probe
    mujoco.mj_forward(model, data)
    rows = [i for i in range(data.nefc) if data.efc_type[i] == mujoco.mjtConstraint.mjCNSTR_CONTACT_FRICTIONLESS]
    if not rows:
        raise RuntimeError("MuJoCo made no contact at the probe pose: the wall plane is not where the task puts it")
    A = float(data.efc_R[rows[0]]) * d / (1.0 - d)  # R = (1 - d) / d A (MuJoCo's regulariser)
    damping = 2.0 * settings.damping_ratio * math.sqrt(stiffness / A)  # c = 2 zeta sqrt(K_e m), m = 1 / A
    solref = np.array([-stiffness * (1.0 - d) * A, -damping * (1.0 - d) * A])
    for g in geoms:
        model.geom_solref[g] = solref
    mujoco.mj_resetData(model, data)
    return {"solref": solref, "solimp": solimp, "A": A, "damping": damping}


def build_arm(true_params, wall, force_axis: int, settings: ContactSettings, sample_time: float,
              q_start) -> MujocoArm:
    """The MuJoCo plant of ilcforce's true plant ``true_params`` against ``wall`` (ilcforce.task.Wall; its normal
    is the task's ``force_axis``), its timestep ``sample_time / settings.steps_per_sample``. ``q_start``: joint
    angles near the wall (the run's start), from which the probe pose for the contact's A is reached."""
    import mujoco

    if not simulates(true_params):
        raise ValueError(f"the MuJoCo cross-check has no MuJoCo model of plant.model = "
                         f"{getattr(true_params, 'model', '?')!r} (its parameters give none: mujoco_model)")
    described = true_params.mujoco_model()
    spec, ee, g, changes = described.spec, described.end_effector, described.g, described.changes
    n = described.task_axes.shape[0]
    spec.compiler.fusestatic = True
    spec.option.gravity = [0.0, 0.0, -g]
    spec.option.timestep = sample_time / settings.steps_per_sample
    spec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{settings.integrator.upper()}")
    for geom in spec.geoms:  # only the tip touches anything: the project's wall meets the end-effector point
        geom.contype, geom.conaffinity = 0, 0
    site_names = {s.name for s in spec.sites}
    body_names = {b.name for b in spec.bodies}
    if ee in site_names:  # (a site's orientation does not move its origin)
        carrier, offset = spec.site(ee).parent, np.array(spec.site(ee).pos, dtype=np.float64)
    elif ee in body_names:
        carrier, offset = spec.body(ee), np.zeros(3)
    else:
        raise ValueError(f"the model file has no body or site {ee!r}")
    carrier.add_site(name=SITE, pos=offset)
    carrier.add_geom(name=TIP, type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[TIP_RADIUS, 0, 0], pos=offset,
                     contype=1, conaffinity=1, condim=1, mass=0.0)
    frame = wall.frame(n)
    W = frame @ described.task_axes
    normal = W[force_axis]  # the wall's normal in the world frame
    w = wall.sign
    outward = -w * normal  # MuJoCo's plane pushes along its z: towards the robot's side
    z = outward / np.linalg.norm(outward)
    x = np.cross([0.0, 1.0, 0.0], z) if abs(z[1]) < 0.9 else np.cross([1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.array([x, y, z]).T
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, rot.ravel())
    # the plane n . x = y_e + w r: the sphere of radius r then touches it when its centre is on the wall
    spec.worldbody.add_geom(name=WALL, type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
                            pos=(wall.position + w * TIP_RADIUS) * normal, quat=quat, contype=1, conaffinity=1,
                            condim=1)
    try:
        model = spec.compile()
    except Exception as exc:  # noqa: BLE001 - MuJoCo's compiler errors have no common base
        raise ValueError(f"MuJoCo cannot compile the cross-check's model: {' '.join(str(exc).split())}") from None
    body_of = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b): b for b in range(model.nbody)}
    for name, factor in changes:  # as ilcforce scales a link (ilcforce.plants.model_plant / spatial_plant)
        link, _, what = name.rpartition(".")
        b = body_of[link]
        if what == "mass":
            model.body_mass[b] *= factor
        else:
            model.body_inertia[b] *= factor
    data = mujoco.MjData(model)
    mujoco.mj_setConst(model, data)  # body_invweight0 (MuJoCo's A) for the changed masses
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, SITE)
    tip = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, TIP)
    plane = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, WALL)
    # the probe: 5 mm into the wall along its normal (Newton steps on MuJoCo's own kinematics)
    arm = MujocoArm(model, data, site, tip, W, w, force_axis)
    q = np.asarray(q_start, dtype=np.float64).copy()
    for _ in range(20):
        arm.set_state(q, np.zeros(model.nv))
        miss = wall.position + w * 5e-3 - arm.position()[force_axis]
        if abs(miss) < 1e-9:
            break
        push = np.zeros(n)
        push[force_axis] = miss
        q += np.linalg.solve(arm.task_jacobian(), push)
    arm.contact = contact_gains(model, data, (tip, plane), settings, wall.stiffness, q)
    return arm


def describe(arm: MujocoArm, settings: ContactSettings) -> str:
    """One line: MuJoCo's contact and integration parameters of ``arm``."""
    c = arm.contact
    return (f"MuJoCo {_version()}: solref = [{c['solref'][0]:.6g}, {c['solref'][1]:.6g}] (stiffness, damping given "
            f"directly), solimp = [{', '.join(f'{v:g}' for v in c['solimp'])}], A = {c['A']:.6g} 1/kg, "
            f"damper {c['damping']:.4g} N s/m (zeta = {settings.damping_ratio:g}), integrator "
            f"{settings.integrator}, timestep {arm.model.opt.timestep:g} s")


def _version() -> str:
    import mujoco

    return mujoco.__version__

