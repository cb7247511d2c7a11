"""A spatial arm of three joints from a URDF or MJCF model file, behind the n-joint plant interface
(docs/model.md#n-dof, docs/model.md#model-file): ``[plant] model = "spatial_arm"`` with
``[plant.spatial_arm] path, end_effector, g, posture``.

:func:`ilcforce.plants.load_model` reads the file (MuJoCo, once per file version); the simulation calls
only the chain's compiled kernel (``nd_kernel``, allocation-free, ``ilcforce.plants.chain_nd``), which
reads the packed parameters at :attr:`SpatialArm.address`. The task is the end effector's position in the
world frame, three coordinates for three joints; the loop turns it into the wall's frame.

The working mode is the branch of inverse kinematics reached from ``posture`` (joint angles, rad): the
simulation starts there, and the desired motion (tau_d) is followed from it continuously.

This module imports neither MuJoCo nor numba: only building a plant reads the file.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.plants.base import PackedParams, UnreachableError

__all__ = ["SpatialArmParams", "ScaledSpatialArmParams", "SpatialArm", "PARAM_NAMES", "load_spatial"]

#: the keys of ``[plant.spatial_arm]``
PARAM_NAMES = ("path", "end_effector", "g", "posture")
#: what a perturbation may scale, per link: ``<link>.mass`` (kg) and ``<link>.inertia`` (the centroidal tensor)
SCALABLE = ("mass", "inertia")
#: joints of the arm this plant takes: as many as the task's axes (a position in space)
JOINTS = 3


@dataclass(frozen=True)
class SpatialArmParams(PackedParams):
    """The robot of a model file with three joints moving in space: the file (``path``; an experiment file's
    relative path is relative to that file), its end effector (a link or an MJCF site), gravity g (m/s^2,
    along the model's -z) and ``posture``, joint angles (rad) near the working pose (the working mode)."""

    model: ClassVar[str] = "spatial_arm"  # the plants.MODELS key
    units: ClassVar[dict[str, str]] = {"path": "", "end_effector": "", "g": "m/s^2", "posture": "rad"}
    path_keys: ClassVar[tuple[str, ...]] = ("path",)

    path: str = ""
    end_effector: str = ""
    g: float = 9.81
    posture: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not (isinstance(self.g, (int, float)) and math.isfinite(self.g) and self.g >= 0):
            raise ValueError(f"plant.spatial_arm.g must be finite and >= 0, got {self.g!r}")
        if not all(math.isfinite(v) for v in self.posture):
            raise ValueError(f"plant.spatial_arm.posture must be finite joint angles (rad), got {list(self.posture)}")

    @property
    def param_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(f"{link}.{what}" for link in load_spatial(*self._key()).link_names for what in SCALABLE)

    def check(self) -> None:
        """Read the file now: ValueError (one line) for any problem with it."""
        if not self.path:
            raise ValueError("plant.spatial_arm.path must name a URDF or MJCF file (plant.model = \"spatial_arm\")")
        if not self.end_effector:
            raise ValueError("plant.spatial_arm.end_effector must name a link (body) or site of the model file")
        arm = load_spatial(*self._key())
        if arm.n != JOINTS:
            raise ValueError(f"plant.spatial_arm: {self.path} has {arm.n} joints; a spatial arm's task (a point in "
                             f"space) needs {JOINTS}")
        if len(self.posture) != arm.n:
            raise ValueError(f"plant.spatial_arm.posture must have {arm.n} joint angles (rad), got {len(self.posture)}")

    def default_perturbed(self) -> str:
        """The last link's mass."""
        return f"{load_spatial(*self._key()).link_names[-1]}.mass"

    def mujoco_model(self):
        """The robot as MuJoCo simulates it from its file (:class:`~ilcforce.plants.model_file.MujocoModel`);
        the task is the end effector's world position."""
        from ilcforce.plants.model_file import MujocoModel, mujoco_spec

        return MujocoModel(mujoco_spec(self.path), self.end_effector, float(self.g), tuple(self._changes()),
                           np.eye(JOINTS))

    def _key(self):
        try:
            stamp = os.stat(self.path).st_mtime_ns
        except OSError:
            stamp = None
        return self.path, self.end_effector, float(self.g), stamp

    def _changes(self) -> tuple[tuple[str, float], ...]:
        return ()

    def as_array(self) -> np.ndarray:
        """The chain's packed vector (``ilcforce.plants.chain``), with this parameter set's changes."""
        from ilcforce.plants import chain

        arm = load_spatial(*self._key())
        packed = arm.packed.copy()
        for name, factor in self._changes():
            link, _, what = name.rpartition(".")
            start = chain.HEADER + chain.LINK * arm.link_names.index(link)
            if what == "mass":
                packed[start + chain._MASS] *= factor
            else:
                packed[start + chain._INERTIA:start + chain._INERTIA + 9] *= factor
        return packed

    def scaled(self, name: str, factor: float):
        """A copy whose ``<link>.mass`` or ``<link>.inertia`` is multiplied by ``factor``."""
        if name not in self.param_names:
            raise ValueError(f"unknown plant parameter {name!r}; expected one of {', '.join(self.param_names)}")
        return ScaledSpatialArmParams(self.path, self.end_effector, self.g, self.posture,
                                      changes=(*self._changes(), (name, float(factor))))


@dataclass(frozen=True)
class ScaledSpatialArmParams(SpatialArmParams):
    """A model file's spatial arm with link parameters scaled (the true plant of a perturbation)."""

    changes: tuple[tuple[str, float], ...] = ()

    def _changes(self):
        return self.changes


@functools.lru_cache(maxsize=32)
def load_spatial(path: str, end_effector: str, g: float, stamp):
    """The file's arm (``ilcforce.plants.SerialArm``), cached per file version; ValueError, one line."""
    from ilcforce.plants.model_file import load_model

    return load_model(path, end_effector=end_effector, gravity=(0.0, 0.0, -g))


class SpatialArm:
    """A 3-joint arm from a model file, moving in space (docs/model.md#n-dof): the n-joint interface
    (``dimension``, ``address``, ``nd_kernel``, ``nd_width``), inverse kinematics in its working mode, and
    the rigid-body API of :class:`ilcforce.plants.SerialArm` (``forward_kinematics``, ``jacobian``,
    ``joint_inertia``, ``inverse_dynamics``, ...)."""

    params_class = SpatialArmParams
    #: the ahead-of-time module holds the loop on its kernel, one for every chain (ilcforce.plants.chain_nd), the
    #: file's arm read at run time from its packed vector; its tau_d is Python (ilcforce.plants.desired_nd)
    ahead_of_time = "loop"

    @staticmethod
    def shared_nd_kernel():
        """The chain's ``nd_dyn`` every spatial arm runs (``ilcforce.plants.chain_nd.kernel``)."""
        from ilcforce.plants import chain_nd

        return chain_nd.kernel()
    dimension = JOINTS  # joints = task axes (an instance checks its file's arm has as many)

    def check_frame(self, frame: np.ndarray) -> None:
        """Every wall frame suits a spatial arm (``Wall.frame`` has made it orthonormal)."""

    def desired_inputs(self, frame, wall_sign: float, reference_log: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """tau_d and J_X^-T tau_d along the reference on the log grid, by inverse kinematics and the chain's
        inverse dynamics (:func:`ilcforce.plants.desired_nd.desired_inputs_nd`)."""
        from ilcforce.plants.desired_nd import desired_inputs_nd

        return desired_inputs_nd(self, frame, wall_sign, reference_log)

    def __init__(self, params=None):
        from ilcforce.plants.serial_arm import SerialArm

        self.params = params if params is not None else SpatialArmParams()
        self.params.check()
        base = load_spatial(*self.params._key())
        self.arm = SerialArm(self.params.as_array(), joint_names=base.joint_names, link_names=base.link_names,
                             end_effector=base.end_effector, source=base.source)
        self.dimension = self.arm.n
        self.link_names = base.link_names
        self.has_gravity = self.params.g != 0.0
        self.posture = np.asarray(self.params.posture, dtype=np.float64)
        self.working_mode = f"the working mode of posture ({', '.join(f'{v:.4g}' for v in self.posture)}) rad"

    def __getattr__(self, name: str):  # the rigid-body API of the arm
        if name.startswith("_") or name == "arm":
            raise AttributeError(name)
        return getattr(self.arm, name)

    @property
    def address(self) -> int:
        return self.arm.address

    @property
    def nd_width(self) -> int:
        return self.arm.nd_width

    def nd_kernel(self):
        return self.arm.nd_kernel()

    def task_gravity_along(self, positions) -> np.ndarray:
        """G = J^-T G_q (N, world frame) at each end-effector position of ``positions`` (samples, 3) (m), shape
        (samples, 3): the task gravity C3's G block learns (in the wall's frame: R G), the joint angles followed
        along the positions by inverse kinematics from the posture, as the desired motion is."""
        positions = np.asarray(positions, dtype=np.float64)
        if positions.ndim != 2 or positions.shape[1] != 3:
            raise ValueError(f"positions must have shape (samples, 3), got {positions.shape}")
        out, q = np.empty_like(positions), None
        for k, position in enumerate(positions):
            q = self.inverse_kinematics(position, q)
            out[k] = self.arm.task_gravity(q)
        return out

    def inverse_kinematics(self, position, guess=None) -> np.ndarray:
        """Joint angles (rad) in the working mode for the end-effector position P (m, world frame), by
        Newton steps from ``guess`` (default: the posture); raises UnreachableError (one line)."""
        start = self.posture if guess is None else np.asarray(guess, dtype=np.float64)
        q = self.arm.inverse_kinematics(position, start)
        if guess is None and np.max(np.abs(np.angle(np.exp(1j * (q - self.posture))))) > math.pi / 2:
            raise UnreachableError(f"point ({', '.join(f'{v:.6g}' for v in np.asarray(position))}) m is reached at "
                                   f"q = ({', '.join(f'{v:.4g}' for v in q)}) rad, more than 90 degrees from "
                                   f"{self.working_mode}")
        return q


# --------------------------------------------------------------------------------------------
# Linear parametrisation for an adaptive law (ilcforce.plants.adaptive): M ddq_r + C(q, dq) dq_r + g = Y a,
# a the base parameters (the identifiable combinations of the links' inertial parameters). The adaptive law
# computes the chain's whole regressor (ilcforce.plants.chain_nd.slotine_li_regressor) and keeps its base
# columns, which these functions name.
# --------------------------------------------------------------------------------------------

#: the base parameters' units, as an adaptive law's memory describes them
BASE_PARAMETER_UNITS = ("each a link's inertial parameter (kg, kg m or kg m^2, link frame) plus the unidentifiable "
                        "ones it absorbs")
#: an n-joint chain's regressor serves the adaptive law (ilcforce.plants.adaptive.regressor_rows)
CHAIN_REGRESSOR = True


@functools.lru_cache(maxsize=32)
def _base(params):
    from ilcforce.plants import chain

    return chain.base_columns(params.as_array())


def base_columns_of(params) -> list[int]:
    """The chain regressor's columns of the base parameters (``ilcforce.plants.chain.base_columns``)."""
    return list(_base(params)[0])


def base_parameter_names_of(params) -> tuple[str, ...]:
    """The base parameters' names: each the inertial parameter of its column (``forearm.mcx``)."""
    from ilcforce.plants import chain

    links = load_spatial(*params._key()).link_names
    return tuple(chain.inertial_parameter_name(links, c) for c in base_columns_of(params))


def base_parameters(params) -> np.ndarray:
    """a = pi_B + beta pi_D (``ilcforce.plants.chain.base_columns``), shape (n_base,)."""
    from ilcforce.plants import chain

    return chain.base_parameters(params.as_array(), *_base(params))
