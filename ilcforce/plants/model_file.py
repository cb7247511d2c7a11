"""A serial arm read from a URDF or MJCF model file (docs/model.md#model-file): ``load_model``.

MuJoCo's parser reads the file once (it reads both formats and is the lightest of the robotics
libraries on pip); this module turns the compiled model into the packed vector of
``ilcforce.plants.chain`` and never calls MuJoCo again. MuJoCo is imported here only, inside
:func:`load_model`, so nothing else in ilcforce loads it.

What is read, per moving link (a body with one hinge or slide joint, together with every body fixed
to it, e.g. a tool link on a URDF fixed joint): the placement of its frame in the previous link's
frame, the joint's anchor, axis and reference value, and the mass, centre of mass and inertia of
the link and its fixed bodies. Bodies fixed to the world (a URDF base link) do not move and are
left out. Joint limits, damping, friction and stiffness are not part of the rigid-body model and are
not read; armature (rotor inertia added to M) is refused rather than ignored. In a URDF, the
geometry is not read either: URDF gives the dynamics in ``<inertial>`` alone (a link without one is
massless), which also spares loading mesh files.

Before MuJoCo reads anything, :func:`ilcforce.plants.model_refs.scan_model` checks the file and every
file it names (safe to open, bounded in size and in bodies); after parsing, every physical number of
every body, joint and site is checked (finite, in bounds, masses and inertias physical), one line
naming the element (docs/model.md#model-file-limits).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcforce.plants import chain
from ilcforce.plants.model_refs import ModelFileError, scan_model
from ilcforce.plants.serial_arm import SerialArm

__all__ = ["ModelFileError", "load_model", "check_task_dimension", "shipped_models", "resolve_model",
           "referenced_files", "MujocoModel", "mujoco_spec"]

#: MuJoCo's joint types (mjtJoint)
_FREE, _BALL, _SLIDE, _HINGE = 0, 1, 2, 3


#: Largest mass of a body, kg, and longest length (a position, an anchor, a centre of mass, a slide's
#: reference), m: an arm of metres and kilograms, with room to spare; 1e308 kg loaded and every run
#: "diverged at t = 0". A centroidal inertia is bounded by their product, MAX_MASS x MAX_LENGTH^2.
MAX_MASS = 1e6
MAX_LENGTH = 1e3


def shipped_models() -> list[str]:
    """The model files shipped with ilcforce (``experiments/models/``), by file name."""
    from ilcforce.tomlfile import shipped_folder

    folder = shipped_folder()
    models = folder / "models" if folder is not None else None
    return sorted(p.name for p in models.iterdir() if p.suffix in (".xml", ".urdf")) if models and models.is_dir() else []


def resolve_model(path) -> Path:
    """``path`` itself when it exists or names a folder; else, when it is a bare file name of a shipped
    model (``arm3.xml``), that shipped file; else ``path`` unchanged."""
    from ilcforce.tomlfile import shipped_folder

    path = Path(path)
    if path.exists() or len(path.parts) != 1:
        return path
    folder = shipped_folder()
    candidate = folder / "models" / path.name if folder is not None else None
    return candidate if candidate is not None and candidate.is_file() else path


def _one_line(text: str) -> str:
    return "; ".join(part.strip() for part in str(text).splitlines() if part.strip())


def _compile(path: Path, urdf: bool | None = None):
    """The compiled MjModel of ``path`` (a URDF if ``urdf``; None: scan the file first, to know): fixed
    bodies kept apart (a URDF tool link survives), a URDF's geometry left out, every physical number
    checked before and after compiling."""
    if urdf is None:
        urdf = scan_model(path).urdf
    try:
        import mujoco
    except ImportError as exc:  # a dependency of ilcforce; missing only in a broken install
        raise ModelFileError(f"reading a model file needs the mujoco package ({exc})") from None
    warnings: list[str] = []  # MuJoCo's parser prints them (a NaN) on stderr: kept, not printed
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(warnings.append)
    try:
        spec = mujoco.MjSpec.from_file(str(path))
        spec.compiler.fusestatic = False  # MuJoCo's URDF import fuses fixed joints by default: keep the tool link
        if urdf:
            for geom in list(spec.geoms):
                spec.delete(geom)
            for mesh in list(spec.meshes):
                spec.delete(mesh)
        _check_spec(spec, path)
        model = spec.compile()
    except ModelFileError:
        raise
    except ValueError as exc:
        raise ModelFileError(f"{path}: MuJoCo cannot read it: {_one_line(exc)}") from None
    finally:
        mujoco.set_mju_user_warning(previous)
    _check_model(model, path)
    nan = [w for w in warnings if "NaN" in w]
    if nan:  # one the checks above do not read (a damping, a colour): every number of the file is finite
        raise ModelFileError(f"{path}: MuJoCo warns: {_one_line(nan[0])}; every number of a model file must be finite")
    return model


def _bad_numbers(values, bound: float | None = None) -> bool:
    """Whether ``values`` hold a number that is not finite, or (with ``bound``) larger than it in size."""
    values = np.asarray(values, dtype=np.float64)
    return not np.all(np.isfinite(values)) or (bound is not None and bool(np.any(np.abs(values) > bound)))


def _shown(values) -> str:
    return " ".join(f"{float(v):g}" for v in np.ravel(values))


def _check_inertial(path: Path, name: str, mass: float, tensor: np.ndarray) -> None:
    """A body's own mass and inertia (about its centre of mass), as the file gives them."""
    where = f"{path}: body {name!r}"
    if _bad_numbers([mass]) or not 0.0 <= mass <= MAX_MASS:
        raise ModelFileError(f"{where}: mass {mass:g} kg is not a number > 0 and at most {MAX_MASS:g} kg "
                             "(or 0 for a massless body with no inertia)")
    if _bad_numbers(tensor, MAX_MASS * MAX_LENGTH ** 2):
        raise ModelFileError(f"{where}: inertia {_shown(tensor)} is not finite numbers of at most "
                             f"{MAX_MASS * MAX_LENGTH ** 2:g} kg m^2")
    moments = np.linalg.eigvalsh(0.5 * (tensor + tensor.T))
    if mass == 0.0:
        if np.any(tensor != 0.0):
            raise ModelFileError(f"{where}: mass 0 with inertia {_shown(tensor)}; a massless body has none")
        return
    if moments[0] <= 0.0:
        raise ModelFileError(f"{where}: inertia {_shown(tensor)} is not positive definite (principal moments "
                             f"{_shown(moments)} kg m^2)")
    if moments[0] + moments[1] < moments[2] * (1.0 - 1e-9):  # the triangle inequality of a rigid body
        raise ModelFileError(f"{where}: principal moments of inertia {_shown(moments)} kg m^2 break the triangle "
                             "inequality (the two smaller must add up to at least the largest): no rigid body has them")


def _check_spec(spec, path: Path) -> None:
    """Every number the file gives a body, joint or site, as written (MuJoCo's compiler turns a fixed
    body's negative mass into 0 and an unreadable full inertia into none): finite and in bounds, masses
    and inertias physical (:func:`_check_inertial`). One line naming the element."""
    for index, body in enumerate(spec.bodies[1:], start=1):
        name = body.name or f"#{index}"
        for what, values in (("position", body.pos), ("orientation (quat)", body.quat)):
            if _bad_numbers(values, MAX_LENGTH if what == "position" else None):
                raise ModelFileError(f"{path}: body {name!r}: {what} {_shown(values)} is not finite numbers"
                                     + (f" of at most {MAX_LENGTH:g} m" if what == "position" else ""))
        if not body.explicitinertial:
            continue  # none given: a URDF link without <inertial> is massless; an MJCF body's comes from its geoms
        if _bad_numbers(body.ipos, MAX_LENGTH) or _bad_numbers(body.iquat):
            raise ModelFileError(f"{path}: body {name!r}: centre of mass {_shown(body.ipos)} or its orientation "
                                 f"{_shown(body.iquat)} is not finite numbers (of at most {MAX_LENGTH:g} m)")
        full = np.asarray(body.fullinertia, dtype=np.float64)
        if math.isnan(full[0]) and not _bad_numbers(full[1:]) and not np.any(full[1:]):  # not given: the diagonal
            tensor = np.diag(np.asarray(body.inertia, dtype=np.float64))
        else:
            tensor = np.array([[full[0], full[3], full[4]], [full[3], full[1], full[5]], [full[4], full[5], full[2]]])
        _check_inertial(path, name, float(body.mass), tensor)
    for index, joint in enumerate(spec.joints):
        name = joint.name or f"#{index}"
        for what, values, bound in (("anchor (pos)", joint.pos, MAX_LENGTH), ("axis", joint.axis, None),
                                    ("reference (ref)", [joint.ref], MAX_LENGTH)):
            if _bad_numbers(values, bound):
                raise ModelFileError(f"{path}: joint {name!r}: {what} {_shown(values)} is not finite numbers"
                                     + (f" of at most {bound:g}" if bound else ""))
        if not np.any(np.asarray(joint.axis, dtype=np.float64)):
            raise ModelFileError(f"{path}: joint {name!r}: axis 0 0 0 has no direction")
    for index, site in enumerate(spec.sites):
        if _bad_numbers(site.pos, MAX_LENGTH) or _bad_numbers(site.quat):
            raise ModelFileError(f"{path}: site {site.name or f'#{index}'!r}: position {_shown(site.pos)} or "
                                 f"orientation {_shown(site.quat)} is not finite numbers (of at most {MAX_LENGTH:g} m)")


def _check_model(model, path: Path) -> None:
    """The compiled numbers the plant reads (every orientation form turned into a quaternion, every
    inertia from geoms computed), finite and in bounds; one line naming the element."""
    checks = (("body", model.nbody, (("position", model.body_pos, MAX_LENGTH), ("orientation", model.body_quat, None),
                                     ("centre of mass", model.body_ipos, MAX_LENGTH),
                                     ("inertia orientation", model.body_iquat, None),
                                     ("mass", model.body_mass, MAX_MASS),
                                     ("inertia", model.body_inertia, MAX_MASS * MAX_LENGTH ** 2))),
              ("joint", model.njnt, (("anchor", model.jnt_pos, MAX_LENGTH), ("axis", model.jnt_axis, None))),
              ("site", model.nsite, (("position", model.site_pos, MAX_LENGTH), ("orientation", model.site_quat, None))))
    for kind, count, fields in checks:
        for index in range(1 if kind == "body" else 0, count):
            for what, values, bound in fields:
                if _bad_numbers(values[index], bound) or (what in ("mass", "inertia") and np.any(values[index] < 0)):
                    limits = ", at least 0" if what in ("mass", "inertia") else ""
                    limits += f", at most {bound:g} in size" if bound else ""
                    raise ModelFileError(f"{path}: {kind} {_name(model, kind, index)!r}: {what} {_shown(values[index])} "
                                         f"is out of bounds (finite{limits})")
    for j in range(model.njnt):
        value = model.qpos0[model.jnt_qposadr[j]]
        if _bad_numbers([value], MAX_LENGTH):
            raise ModelFileError(f"{path}: joint {_name(model, 'joint', j)!r}: reference {value:g} is not a finite "
                                 f"number of at most {MAX_LENGTH:g}")


def _quat_matrix(quat) -> np.ndarray:
    w, x, y, z = (float(v) for v in quat)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _name(model, kind: str, index: int) -> str:
    import mujoco

    obj = {"body": mujoco.mjtObj.mjOBJ_BODY, "joint": mujoco.mjtObj.mjOBJ_JOINT, "site": mujoco.mjtObj.mjOBJ_SITE}[kind]
    return mujoco.mj_id2name(model, obj, index) or f"#{index}"


def _chain(model, path: Path) -> list[int]:
    """The moving bodies (one joint each) in order from the base; raises unless they form one serial chain."""
    if model.neq:
        raise ModelFileError(f"{path}: {model.neq} equality constraint(s) (a closed chain or coupled joints); "
                             "only an open serial chain can be a plant")
    for j in range(model.njnt):
        kind = int(model.jnt_type[j])
        if kind == _FREE:
            raise ModelFileError(f"{path}: joint {_name(model, 'joint', j)!r} is a free joint (a floating base); "
                                 "the base must be fixed to the world")
        if kind == _BALL:
            raise ModelFileError(f"{path}: joint {_name(model, 'joint', j)!r} is a ball joint; "
                                 "only hinge (revolute) and slide (prismatic) joints are supported")
    if model.njnt == 0:
        raise ModelFileError(f"{path}: the model has no joint")
    moving = []
    for b in range(1, model.nbody):
        count = int(model.body_jntnum[b])
        if count > 1:
            raise ModelFileError(f"{path}: body {_name(model, 'body', b)!r} has {count} joints; "
                                 "give each joint a body of its own")
        if count == 1:
            moving.append(b)
    previous = None
    for b in moving:
        ancestor = _moving_ancestor(model, int(model.body_parentid[b]))
        if ancestor != previous:
            other = moving[moving.index(b) - 1]
            where = "the world" if ancestor is None else repr(_name(model, "body", ancestor))
            raise ModelFileError(f"{path}: {where} carries both {_name(model, 'body', other)!r} and "
                                 f"{_name(model, 'body', b)!r}: a branching tree, not a serial chain")
        previous = b
    armature = [j for j in range(model.njnt) if model.dof_armature[model.jnt_dofadr[j]] != 0.0]
    if armature:
        raise ModelFileError(f"{path}: joint {_name(model, 'joint', armature[0])!r} has armature "
                             f"{model.dof_armature[model.jnt_dofadr[armature[0]]]:g}; rotor inertia is not modelled, remove it")
    if np.any(model.body_gravcomp != 0.0):
        raise ModelFileError(f"{path}: gravity compensation (gravcomp) is not modelled, remove it")
    return moving


def _moving_ancestor(model, body: int) -> int | None:
    """The nearest body at or above ``body`` that has a joint; None if it is fixed to the world."""
    while body != 0:
        if model.body_jntnum[body]:
            return body
        body = int(model.body_parentid[body])
    return None


def _pose_in(model, body: int, frame: int | None):
    """(R, t) of ``body``'s frame in the frame of ``frame`` (a moving ancestor, or the world when None),
    at the joints' reference values, composing the fixed placements in between."""
    R, t = np.eye(3), np.zeros(3)
    while body != 0 and body != frame:
        Rb = _quat_matrix(model.body_quat[body])
        t = Rb @ t + model.body_pos[body]
        R = Rb @ R
        body = int(model.body_parentid[body])
    return R, t


def _link_inertia(model, link: int, members: list[int]):
    """(mass, centre of mass, inertia about it) of ``link`` and the fixed ``members`` in the link frame."""
    masses, centres, tensors = [], [], []
    for b in members:
        R, t = _pose_in(model, b, link) if b != link else (np.eye(3), np.zeros(3))
        Ri = R @ _quat_matrix(model.body_iquat[b])
        masses.append(float(model.body_mass[b]))
        centres.append(R @ model.body_ipos[b] + t)
        tensors.append(Ri @ np.diag(model.body_inertia[b]) @ Ri.T)
    mass = sum(masses)
    if mass == 0.0:
        return 0.0, np.zeros(3), np.zeros((3, 3))
    com = sum(m * c for m, c in zip(masses, centres)) / mass
    inertia = np.zeros((3, 3))
    for m, c, tensor in zip(masses, centres, tensors):
        d = c - com
        inertia += tensor + m * (d @ d * np.eye(3) - np.outer(d, d))
    return mass, com, 0.5 * (inertia + inertia.T)


def _end_effector(model, path: Path, name: str, moving: list[int]):
    """(link index, offset in that link's frame) of the body or site ``name``."""
    import mujoco

    body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)
    if body >= 0 and site >= 0:
        raise ModelFileError(f"{path}: {name!r} names both a body and a site; rename one")
    if body < 0 and site < 0:
        bodies = [_name(model, "body", b) for b in range(1, model.nbody)]
        sites = [_name(model, "site", s) for s in range(model.nsite)]
        known = f"links (bodies): {', '.join(bodies) or 'none'}" + (f"; sites: {', '.join(sites)}" if sites else "")
        raise ModelFileError(f"{path}: no end effector {name!r}; {known}")
    if site >= 0:
        body, offset = int(model.site_bodyid[site]), np.array(model.site_pos[site], dtype=np.float64)
    else:
        offset = np.zeros(3)
    link = _moving_ancestor(model, body) if body > 0 else None
    if link is None:
        raise ModelFileError(f"{path}: end effector {name!r} is fixed to the world; name a body or site that moves")
    R, t = _pose_in(model, body, link) if body != link else (np.eye(3), np.zeros(3))
    return moving.index(link), R @ offset + t


def _check_gravity(gravity) -> np.ndarray:
    g = np.asarray(gravity, dtype=np.float64)
    if g.shape != (3,) or not np.all(np.isfinite(g)):
        raise ModelFileError(f"gravity must be three finite numbers (m/s^2, world frame), got {gravity!r}")
    return g


def load_model(path, end_effector: str, gravity=(0.0, 0.0, -9.81)) -> SerialArm:
    """The plant of the serial arm in the URDF or MJCF file ``path`` (a bare name such as ``arm3.xml``
    also finds a shipped model, :func:`shipped_models`), its end effector the body (link) or site
    ``end_effector``, gravity the world vector ``gravity`` (m/s^2; the file's own is not used).
    Raises :class:`ModelFileError` (one line) for a file that is missing or unreadable, that MuJoCo
    cannot parse, or that is not an open serial chain of hinge and slide joints on a fixed base, and
    for an end effector that does not exist."""
    g = _check_gravity(gravity)
    path = resolve_model(path)
    scan = scan_model(path)  # the file and every file it names, safe and bounded (model_refs.py)
    model = _compile(path, scan.urdf)
    moving = _chain(model, path)
    ee_link, ee_offset = _end_effector(model, path, str(end_effector), moving)
    n = len(moving)
    members: dict[int, list[int]] = {b: [b] for b in moving}
    for b in range(1, model.nbody):
        if not model.body_jntnum[b]:
            owner = _moving_ancestor(model, b)
            if owner is not None:
                members[owner].append(b)
    p = np.zeros(chain.HEADER + chain.LINK * n)
    p[0], p[1], p[2:5], p[5:8] = n, ee_link, ee_offset, g
    for i, b in enumerate(moving):
        j = int(model.body_jntadr[b])
        R, t = _pose_in(model, b, moving[i - 1] if i else None)
        mass, com, inertia = _link_inertia(model, b, members[b])
        axis = np.array(model.jnt_axis[j], dtype=np.float64)
        axis /= math.sqrt(axis @ axis)
        block = [chain.HINGE if int(model.jnt_type[j]) == _HINGE else chain.SLIDE, float(model.qpos0[model.jnt_qposadr[j]]),
                 *t, *R.ravel(), *model.jnt_pos[j], *axis, mass, *com, *inertia.ravel()]
        start = chain.HEADER + chain.LINK * i
        p[start:start + chain.LINK] = block
    return SerialArm(p, joint_names=tuple(_name(model, "joint", int(model.body_jntadr[b])) for b in moving),
                     link_names=tuple(_name(model, "body", b) for b in moving), end_effector=str(end_effector),
                     source=str(path))


def referenced_files(path) -> list[Path]:
    """Every file loading the model file ``path`` reads: the file, its includes and the assets that
    exist (:func:`ilcforce.plants.model_refs.scan_model`); :class:`ModelFileError` if it is refused."""
    return scan_model(resolve_model(path)).files


def check_task_dimension(plant: SerialArm, task_dimension: int) -> None:
    """Raise :class:`ModelFileError` unless the arm has as many joints as the task has dimensions
    (the methods need a square Jacobian: no redundancy, no missing freedom)."""
    if plant.n != int(task_dimension):
        raise ModelFileError(f"{plant.source}: the robot has {plant.n} joints but the task has {int(task_dimension)} "
                             "dimensions; they must be equal")


@dataclass(frozen=True)
class MujocoModel:
    """A robot as MuJoCo simulates it (the MuJoCo cross-check, docs/crosscheck.md): ``spec`` (an ``MjSpec``, not
    compiled), its end effector (a body or site name), gravity g (m/s^2 along -z), the link changes of a
    perturbed true plant (``(("<link>.mass", factor), ...)``, as :meth:`~ilcforce.plants.model_plant.ModelFileParams.scaled`
    makes them) and the task coordinates' axes in the model's world frame (n x 3)."""

    spec: object
    end_effector: str
    g: float
    changes: tuple
    task_axes: np.ndarray


def mujoco_spec(path):
    """The ``MjSpec`` MuJoCo reads from ``path`` (a shipped model's bare name too), for MuJoCo to simulate; the
    file was checked when its plant was configured (:func:`load_model`)."""
    import mujoco

    try:
        return mujoco.MjSpec.from_file(str(resolve_model(path)))
    except Exception as exc:  # noqa: BLE001 - MuJoCo's parser errors have no common base
        raise ModelFileError(f"{path}: MuJoCo cannot read it: {_one_line(exc)}") from None
