"""A 2-joint arm from a URDF or MJCF model file, moving in a plane, behind the 2-DOF plant interface
(docs/model.md#model-file): ``[plant] model = "file_arm"`` with ``[plant.file_arm] path, end_effector``.

:func:`ilcforce.plants.load_model` reads the file (MuJoCo, once); this plant's kernels
(``ilcforce.plants.planar_kernels``) are compiled once for every 2-joint chain and read the chain's
packed parameters from the address ``p``. The task plane is the plane normal to the two parallel
hinge axes; its axes are stated by :func:`ilcforce.plants.planar_kernels.plane` (for
``experiments/models/serial2r.xml``: the model's x and z are the task's x and y, the serial 2R arm's).

This module imports neither MuJoCo nor numba: only building a plant reads the file.
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ilcforce.plants.base import PackedParams, Plant

__all__ = ["ModelFileParams", "ScaledModelFileParams", "PlanarArm", "PARAM_NAMES", "ELBOWS", "load_planar"]

#: the keys of ``[plant.file_arm]``
PARAM_NAMES = ("path", "end_effector", "elbow", "g")
#: working modes: the sign of sin(beta), beta link 2's angle from link 1 in the task plane
ELBOWS = {"up": 1.0, "down": -1.0}
#: what a perturbation may scale, per link: ``<link>.mass`` (kg) and ``<link>.inertia`` (the centroidal tensor)
SCALABLE = ("mass", "inertia")


@dataclass(frozen=True)
class ModelFileParams(PackedParams):
    """The robot of a model file: the file (``path``; an experiment file's relative path is relative
    to that file), its end effector (a body/link or an MJCF site), the working mode (``elbow``: "up",
    link 2's angle from link 1 in the task plane in (0, pi), or "down") and gravity g (m/s^2, along the
    model's -z; >= 0)."""

    model: ClassVar[str] = "file_arm"  # the plants.MODELS key
    units: ClassVar[dict[str, str]] = {"path": "", "end_effector": "", "elbow": "", "g": "m/s^2"}
    #: keys holding a file's path: an experiment file's relative path is read relative to that file
    #: (ilcforce.config_load), and the configuration keeps it absolute
    path_keys: ClassVar[tuple[str, ...]] = ("path",)

    path: str = ""
    end_effector: str = ""
    elbow: str = "up"
    g: float = 9.81

    def __post_init__(self) -> None:
        if self.elbow not in ELBOWS:
            raise ValueError(f"plant.file_arm.elbow must be one of {', '.join(ELBOWS)}, got {self.elbow!r}")
        if not (isinstance(self.g, (int, float)) and math.isfinite(self.g) and self.g >= 0):
            raise ValueError(f"plant.file_arm.g must be finite and >= 0, got {self.g!r}")

    # the parameter names a perturbation may scale come from the file
    @property
    def param_names(self) -> tuple[str, ...]:  # type: ignore[override]
        return tuple(f"{link}.{what}" for link in load_planar(*self._key()).link_names for what in SCALABLE)

    def check(self) -> None:
        """Read the file now: ValueError (one line) for any problem with it."""
        if not self.path:
            raise ValueError("plant.file_arm.path must name a URDF or MJCF file (plant.model = \"file_arm\")")
        if not self.end_effector:
            raise ValueError("plant.file_arm.end_effector must name a link (body) or site of the model file")
        load_planar(*self._key())

    def default_perturbed(self) -> str:
        """The last link's mass."""
        return f"{load_planar(*self._key()).link_names[-1]}.mass"

    def mujoco_model(self):
        """The robot as MuJoCo simulates it from its file (:class:`~ilcforce.plants.model_file.MujocoModel`);
        the task axes are the plane's (:attr:`PlanarArm.task_axes`)."""
        from ilcforce.plants.model_file import MujocoModel, mujoco_spec

        return MujocoModel(mujoco_spec(self.path), self.end_effector, float(self.g), tuple(self._changes()),
                           PlanarArm(self).task_axes)

    def _key(self):
        try:
            stamp = os.stat(self.path).st_mtime_ns
        except OSError:
            stamp = None
        return self.path, self.end_effector, self.elbow, float(self.g), stamp

    def _changes(self) -> tuple[tuple[str, float], ...]:
        return ()

    def as_array(self) -> np.ndarray:
        """The packed vector of the plant's kernels (``ilcforce.plants.planar_kernels``)."""
        packed = load_planar(*self._key()).packed.copy()
        for name, factor in self._changes():
            _scale(packed, load_planar(*self._key()).link_names, name, factor)
        return packed

    def scaled(self, name: str, factor: float):
        """A copy whose link parameter ``name`` (``<link>.mass`` or ``<link>.inertia``) is multiplied by ``factor``."""
        if name not in self.param_names:
            raise ValueError(f"unknown plant parameter {name!r}; expected one of {', '.join(self.param_names)}")
        return ScaledModelFileParams(self.path, self.end_effector, self.elbow, self.g,
                                     changes=(*self._changes(), (name, float(factor))))


@dataclass(frozen=True)
class ScaledModelFileParams(ModelFileParams):
    """A model file's robot with link parameters scaled (the true plant of a perturbation); not a
    configuration table."""

    changes: tuple[tuple[str, float], ...] = ()

    def _changes(self):
        return self.changes


class _Planar:
    """A loaded file's packed vector and its moving links' names."""

    def __init__(self, packed, link_names) -> None:
        self.packed = packed
        self.link_names = link_names


@functools.lru_cache(maxsize=32)
def load_planar(path: str, end_effector: str, elbow: str, g: float, stamp) -> _Planar:
    """The packed vector of a 2-joint planar arm (cached per file version); ValueError, one line."""
    from ilcforce.plants import planar_kernels
    from ilcforce.plants.model_file import load_model

    arm = load_model(path, end_effector=end_effector, gravity=(0.0, 0.0, -g))
    header = planar_kernels.plane(arm, ELBOWS[elbow])
    packed = np.concatenate([header, arm.packed])
    packed.setflags(write=False)
    return _Planar(packed, arm.link_names)


def _scale(packed: np.ndarray, links: tuple[str, ...], name: str, factor: float) -> None:
    from ilcforce.plants import chain, planar_kernels

    link, _, what = name.rpartition(".")
    start = planar_kernels.PLANE + chain.HEADER + chain.LINK * links.index(link)
    if what == "mass":
        packed[start + chain._MASS] *= factor
    else:
        packed[start + chain._INERTIA:start + chain._INERTIA + 9] *= factor


class PlanarArm(Plant):
    """A 2-joint arm from a model file (docs/model.md#model-file), gravity along the model's -z."""

    params_class = ModelFileParams
    #: its kernels are numba's (not in the ahead-of-time module: any file's arm runs them)
    ahead_of_time = False

    def __init__(self, params=None):
        super().__init__(params)
        from ilcforce.plants import planar_kernels

        self.link_names = load_planar(*self.params._key()).link_names
        self.working_mode = (f"the working mode elbow {self.params.elbow} (link 2's angle from link 1 in the task "
                             f"plane in {'(0, pi)' if self.params.elbow == 'up' else '(-pi, 0)'})")
        # gravity moves the arm if it has a part in the plane
        g = self._p[planar_kernels.PLANE + 5:planar_kernels.PLANE + 8]
        self.has_gravity = bool(abs(self._p[0:3] @ g) + abs(self._p[3:6] @ g) > 0.0)

    @staticmethod
    def kernels():
        from ilcforce.plants import planar_kernels

        return planar_kernels.kernels()

    @staticmethod
    def nd_kernel():
        from ilcforce.plants import planar_kernels

        return planar_kernels.nd_kernel()

    @property
    def task_axes(self) -> np.ndarray:
        """The task's x and y axes in the model's world frame, shape (2, 3)."""
        return np.array([self._p[0:3], self._p[3:6]])

    def potential_energy(self, theta) -> float:
        """V = -sum_i m_i g . c_i (J), zero with every centre of mass at the world origin."""
        from ilcforce.plants import chain, planar_kernels

        q = np.asarray(theta, dtype=np.float64)
        return float(chain.potential_energy(np.ascontiguousarray(self._p[planar_kernels.PLANE:]), q))


# --------------------------------------------------------------------------------------------
# Linear parametrisation for an adaptive law (ilcforce.plants.adaptive): Dq ddq_r + Cq(q, dq) dq_r + G_q
# = Y a, a the base parameters (the identifiable combinations of the links' inertial parameters)
# --------------------------------------------------------------------------------------------

#: the longest packed vector of this plant (a 2-joint chain), the room a law's gains keep for it
PACKED_LENGTH = 20 + 8 + 2 * 33
#: the base parameters' units, as an adaptive law's memory describes them
BASE_PARAMETER_UNITS = ("each a link's inertial parameter (kg, kg m or kg m^2, link frame) plus the unidentifiable "
                        "ones it absorbs")
def _chain_part(params) -> np.ndarray:
    from ilcforce.plants import planar_kernels

    return np.ascontiguousarray(params.as_array()[planar_kernels.PLANE:])


def base_parameter_names_of(params) -> tuple[str, ...]:
    """The base parameters' names: each the inertial parameter of its column (``link2.mcx``)."""
    from ilcforce.plants import chain

    links = load_planar(*params._key()).link_names
    columns, _ = chain.base_columns(_chain_part(params))
    return tuple(chain.inertial_parameter_name(links, c) for c in columns)


def base_parameters(params) -> np.ndarray:
    """a = pi_B + beta pi_D (ilcforce.plants.chain.base_columns), shape (n_base,)."""
    from ilcforce.plants import chain

    cp = _chain_part(params)
    return chain.base_parameters(cp, *chain.base_columns(cp))


def __getattr__(name: str):
    if name == "regressor":  # compiled, in the kernels' module (imports it only when asked)
        from ilcforce.plants import planar_kernels

        return planar_kernels.regressor
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
