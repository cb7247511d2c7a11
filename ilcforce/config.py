"""Experiment configuration: a tree of frozen dataclasses, and its TOML/JSON serialisation.

:class:`Config` is a whole experiment; each field is one TOML table (below). The tree's own
dataclasses check single values in ``__post_init__``; building the tree from a TOML file and
``--set`` overrides, with every field validated and a one-line :class:`ConfigError` naming the bad
one, is :mod:`ilcforce.config_load` (:func:`~ilcforce.config_load.load_config`). ``to_toml``
writes the resolved configuration back (a minimal TOML writer at the end: tomllib only reads).

TOML layout (every table and key optional; see ``experiments/paper.toml``)::

    [experiment]  name, description, seed, iterations
    [plant]       model (a key of ilcforce.plants.MODELS: "fivebar", the paper's robot, "serial2r", or "file_arm")
    [plant.<model>]  each robot's nominal parameters (five-bar: L1 ... I4, Table 1; 2R arm: L1 ... I2, g;
                  a model file's robot: path, end_effector, elbow, g)
    [plant.perturbation]  parameter, factor, from_iteration
    [wall]        position, stiffness, damping, friction, friction_velocity, force_sign (normal, tangent: a spatial arm)
    [reference]   duration, x_amplitude, ...
    [simulation]  sample_time, substeps, log_every, acceleration, filter_hz, torque_bound, initial_position,
                  initial_velocity, implicit_fallback
    [noise]       disturbance_amplitude, ..., encoder, joint_rate, force_sensor, scale
    [surface]     selection, lambda_p, lambda_f1, lambda_f2          (eq. 8, shared by all methods)
    [tuning]      source, withheld, methods, cap_reference, cap      (set by `ilcforce tune` in a tuned file)
    [c1] [c2] [c3] [smc-bl] ... one per registered method            (each method's own gains)

A method family shares its keys: a key set in ``[c3]`` (or by ``--set c3.KEY=...``) reaches every
method whose gains extend C3's (``c3-leak``) unless that method's own table sets it
(:func:`ilcforce.config_load.inherited_gains`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field

import numpy as np

from ilcforce.controllers import REGISTRY
from ilcforce.controllers.base import check_vector
from ilcforce.noise import NoiseModel
from ilcforce.plants import DEFAULT_MODEL, MODELS, make_plant, params_class, perturbed_parameter
from ilcforce.simulate import SimulationSettings, force_axis
from ilcforce.config_ranges import experiment_name_problem
from ilcforce.task import Reference, Wall


class ConfigError(ValueError):
    """An invalid experiment configuration; the message is one line naming the bad field."""


@dataclass(frozen=True)
class ExperimentInfo:
    name: str = "paper"  # names the results folder results/<name>/
    description: str = "The paper's setup (the defaults of docs/model.md)"
    seed: int = 0  # root of every random draw: (seed, iteration) -> disturbance and noise
    iterations: int = 20  # number of iterations j = 0 .. iterations - 1

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"experiment.seed must be >= 0, got {self.seed}")
        if self.iterations < 1:
            raise ValueError(f"experiment.iterations must be >= 1, got {self.iterations}")
        problem = experiment_name_problem(self.name)  # the one rule (it names folders of results and report)
        if problem:
            raise ValueError(f"experiment.name {self.name!r} {problem}")


@dataclass(frozen=True)
class Perturbation:
    """The true plant's parameter change (Section 4.1: m3 x 1.4 from j = 10); the nominal model never changes."""

    parameter: str = ""  # one of the plant model's parameter names; "" = the model's own (ilcforce.plants.perturbed_parameter)
    factor: float = 1.4  # multiplier applied to the true plant
    from_iteration: int = 10  # first iteration with the changed plant

    def __post_init__(self) -> None:
        if not (math.isfinite(self.factor) and self.factor > 0):
            raise ValueError(f"plant.perturbation.factor must be finite and positive, got {self.factor!r}")
        if self.from_iteration < 0:
            raise ValueError(f"plant.perturbation.from_iteration must be >= 0, got {self.from_iteration}")


class _PlantConfigMethods:
    """The methods of :class:`PlantConfig` (its fields come from the plant registry)."""

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"plant.model must be one of {', '.join(MODELS)}, got {self.model!r}")
        nominal = self.nominal()
        check = getattr(nominal, "check", None)
        if check is not None:  # a robot read from a file: read it now (one-line errors, before any run)
            check()
        names = tuple(nominal.param_names) if check is not None else tuple(f.name for f in dataclasses.fields(nominal))
        p = self.perturbation
        if p.parameter == "":  # the model's default perturbation (docs/model.md#perturbation)
            default = perturbed_parameter(self.model) or nominal.default_perturbed()
            object.__setattr__(self, "perturbation", dataclasses.replace(p, parameter=default))
        elif p.parameter not in names:
            raise ValueError(f"plant.perturbation.parameter must be one of {', '.join(names)} for "
                             f"plant.model = {self.model!r}, got {p.parameter!r}")

    def nominal(self):
        """The nominal parameters of the selected model (what the controllers' model uses)."""
        return getattr(self, self.model)

    def links(self):
        """Alias of :meth:`nominal` (the name used before the plant interface)."""
        return self.nominal()

    def true_plant(self, iteration: int):
        """The plant integrated in iteration j (perturbed from ``from_iteration`` on)."""
        nominal = self.nominal()
        p = self.perturbation
        return nominal.scaled(p.parameter, p.factor) if iteration >= p.from_iteration else nominal

    @property
    def has_gravity(self) -> bool:
        """True if the selected robot has a gravity vector (C3 then learns Theta's G block)."""
        return make_plant(self.nominal()).has_gravity


def _plant_config_class() -> type:
    """PlantConfig: ``model`` (a key of ilcforce.plants.MODELS, the paper's robot by default), one field
    per registered robot holding its nominal parameters (TOML ``[plant.<model>]``, in registry order),
    and ``perturbation``. Made from the registry so that this module names no robot."""
    robots = [(model, params_class(model), field(default_factory=params_class(model))) for model in MODELS]
    return dataclasses.make_dataclass(
        "PlantConfig",
        [("model", str, field(default=DEFAULT_MODEL)), *robots,
         ("perturbation", Perturbation, field(default_factory=Perturbation))],
        bases=(_PlantConfigMethods,), frozen=True,
        namespace={"__module__": __name__, "__doc__": """The robot (``model``), each model's nominal parameters, and the true plant's perturbation.

    Only the selected model's table is used; the others keep their defaults.
    """})


#: the robot (``model``), each registered model's nominal parameters, and the true plant's perturbation
PlantConfig = _plant_config_class()


@dataclass(frozen=True)
class SurfaceGains:
    """Selection and sliding-surface gains of eqs. (6)-(8), shared by every method (erratum 2)."""

    # one entry per task axis: 2 for a planar robot (x, y), 3 for a spatial one (u, v, n: docs/model.md#wall-plane)
    selection: tuple[float, ...] = (0.0, 1.0)  # s: S = diag(s) selects the force axis (y)
    lambda_p: tuple[float, ...] = (2.0, 0.0)  # 1/s
    lambda_f1: tuple[float, ...] = (0.0, 1e-3)  # m/(N s)
    lambda_f2: tuple[float, ...] = (0.0, 1e-4)  # m/N

    def __post_init__(self) -> None:
        n = len(self.selection)
        if n not in (2, 3):
            raise ValueError(f"surface.selection must have 2 entries (a planar task) or 3 (a spatial one), got {n}")
        for name in ("selection", "lambda_p", "lambda_f1", "lambda_f2"):
            check_vector(f"surface.{name}", getattr(self, name), n)
        if force_axis(self.selection) != n - 1:
            # the wall's normal is the task frame's last axis (ilcforce.task.Wall.frame), where the reference
            # carries F_d and the plant presses: another force axis would press the wall along a tangent
            raise ValueError(f"surface.selection must select the wall's normal, the task's last axis "
                             f"({', '.join(['0'] * (n - 1) + ['1'])}); got {list(self.selection)}")

    @property
    def dimension(self) -> int:
        """The task's axes: 2 or 3."""
        return len(self.selection)


@dataclass(frozen=True)
class TuningInfo:
    """What a tuned experiment file (written by ``ilcforce tune``) says of its gains: the tuning that chose
    them, and the methods it found no stable gains for under its chattering cap (their sections keep the
    experiment's gains, and no command runs them with this file)."""

    source: str = ""  # the tuning's name; "" for an experiment not written by a tuning
    withheld: tuple[str, ...] = ()
    #: the methods the tuning searched; () in a file that does not say (every method then counts as tuned).
    #: A method registered after the tuning ran has no tuned gains here and is refused like a withheld one.
    methods: tuple[str, ...] = ()
    cap_reference: str = ""  # the method whose chattering (with the experiment's gains) is the cap
    cap: tuple[float, ...] = ()  # the cap: settled H per task axis (N) on the tuning's held-out seeds

    def __post_init__(self) -> None:
        for key, names in (("withheld", self.withheld), ("methods", self.methods)):
            for method in names:
                if method not in REGISTRY:
                    raise ValueError(f"tuning.{key}: unknown method {method!r}")
        if self.cap_reference and self.cap_reference not in REGISTRY:
            raise ValueError(f"tuning.cap_reference: unknown method {self.cap_reference!r}")
        if not all(math.isfinite(c) and c > 0 for c in self.cap):
            raise ValueError(f"tuning.cap must hold positive numbers (N), got {list(self.cap)}")

    def refusal(self, method: str) -> str | None:
        """One line saying why ``method`` may not run with this file, or None when it may."""
        if self.methods and method not in self.methods:
            return (f"{method} was not tuned by {self.source} (its [tuning] methods: {', '.join(self.methods)}): "
                    "run it with the untuned experiment, or rerun the tuning with it")
        if method not in self.withheld:
            return None
        return (f"{method} has no gains in this tuned experiment: the tuning {self.source} found no stable gains "
                "under its chattering cap ([tuning] withheld); run it with the untuned experiment")


def _default_gains() -> dict[str, object]:
    return {name: spec.gains_class() for name, spec in REGISTRY.items()}


@dataclass(frozen=True)
class Config:
    """A whole experiment. ``gains`` maps each registered method name to its gains dataclass; each is
    also an attribute: ``config.c3`` is ``config.gains["c3"]``, ``config.smc_bl`` is
    ``config.gains["smc-bl"]``."""

    experiment: ExperimentInfo = field(default_factory=ExperimentInfo)
    plant: PlantConfig = field(default_factory=PlantConfig)
    wall: Wall = field(default_factory=Wall)
    reference: Reference = field(default_factory=Reference)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    noise: NoiseModel = field(default_factory=NoiseModel)
    surface: SurfaceGains = field(default_factory=SurfaceGains)
    tuning: TuningInfo = field(default_factory=TuningInfo)
    gains: dict = field(default_factory=_default_gains)

    def __getattr__(self, name: str):
        # Only reached when ordinary lookup fails: ``config.c3`` is ``config.gains["c3"]``, and a method
        # whose name has a hyphen is reachable with an underscore (``config.smc_bl``), as a notebook
        # user types it. Private and special names are never gains (copy and pickle probe for them).
        gains = self.__dict__.get("gains")
        if gains is not None and not name.startswith("_"):
            for key in (name, name.replace("_", "-")):
                if key in gains:
                    return gains[key]
        sections = [f.name for f in dataclasses.fields(self) if f.name != "gains"]
        methods = ", ".join(k.replace("-", "_") for k in (gains or {}))
        raise AttributeError(f"'Config' has no attribute {name!r} (sections: {', '.join(sections)}; "
                             f"methods' gains: {methods})")

    def __dir__(self):
        return sorted(set(super().__dir__()) | {k.replace("-", "_") for k in self.__dict__.get("gains", {})})

    @property
    def n_control(self) -> int:
        return self.simulation.n_control(self.reference.duration)

    @property
    def n_log(self) -> int:
        return self.simulation.n_log(self.reference.duration)

    def control_times(self) -> np.ndarray:
        return np.arange(self.n_control) * self.simulation.sample_time

    @property
    def dimension(self) -> int:
        """The task's axes (= the robot's joints): 2, or 3 for a spatial arm (docs/model.md#n-dof)."""
        return self.surface.dimension

    def reference_samples(self) -> np.ndarray:
        """(n_control, 6 n) reference on the control grid (``ilcforce.task`` layout, n = :attr:`dimension`)."""
        return self.reference.sample(self.control_times(), self.wall, self.dimension)

    def to_dict(self) -> dict:
        """Plain nested dict in the TOML layout (round-trips through
        :func:`ilcforce.config_load.config_from_dict`)."""
        out = {}
        for f in dataclasses.fields(self):
            if f.name == "gains":
                continue
            out[f.name] = _as_plain(getattr(self, f.name))
        for name, g in self.gains.items():
            out[name] = _as_plain(g)
        return out

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def to_toml(self) -> str:
        return dumps_toml(self.to_dict())


def _as_plain(obj):
    if dataclasses.is_dataclass(obj):
        return {f.name: _as_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, tuple):
        return [_as_plain(v) for v in obj]
    return obj


# ------------------------------------------------------------------------------------------------
# a minimal TOML writer for the resolved configuration (tomllib only reads)
# ------------------------------------------------------------------------------------------------

def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {value!r} as TOML")


def dumps_toml(data: dict, prefix: str = "") -> str:
    """Serialise a nested dict of scalars and lists as TOML tables."""
    lines = []
    scalars = {k: v for k, v in data.items() if not isinstance(v, dict)}
    tables = {k: v for k, v in data.items() if isinstance(v, dict)}
    if prefix and scalars:
        lines.append(f"[{prefix}]")
    for key, value in scalars.items():
        lines.append(f"{key} = {_toml_value(value)}")
    for key, value in tables.items():
        if lines:
            lines.append("")
        lines.append(dumps_toml(value, f"{prefix}.{key}" if prefix else key).rstrip("\n"))
    return "\n".join(lines) + "\n"
