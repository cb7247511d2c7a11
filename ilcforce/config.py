"""Experiment configuration: a tree of frozen dataclasses loaded from TOML plus overrides.

One loader (:func:`load_config`) builds and validates every field and names the bad one in a
one-line :class:`ConfigError`. With no file, :func:`default_config` is the paper's setup
(SPEC sections 1-6); ``experiments/paper.toml`` spells the same values out and a test pins that the
two agree.

TOML layout (every table and key optional; see ``experiments/paper.toml``)::

    [experiment]  name, description, seed, iterations
    [plant]       model ("fivebar" | "serial2r")
    [plant.fivebar]  L1 ... I4 (Table 1)   [plant.serial2r]  L1 ... I2, g (SPEC 8)
    [plant.perturbation]  parameter, factor, from_iteration
    [wall]        position, stiffness, force_sign
    [reference]   duration, x_amplitude, ...
    [simulation]  sample_time, substeps, log_every, acceleration, filter_hz, torque_bound, initial_position,
                  initial_velocity, implicit_fallback
    [noise]       disturbance_amplitude, ..., encoder, joint_rate, force_sensor
    [surface]     selection, lambda_p, lambda_f1, lambda_f2          (eq. 8, shared by all methods)
    [c1] [c2] [c3] [smc-bl] ... one per registered method            (each method's own gains)
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ilcforce.config_ranges import (DEFAULT_RANGES, MAX_RUN_BYTES, MAX_STEPS_PER_ITERATION,  # noqa: F401
                                    MAX_STRING, RANGES, Range, range_of)
from ilcforce.controllers import REGISTRY
from ilcforce.controllers.base import check_vector
from ilcforce.noise import NoiseModel
from ilcforce.plants import MODELS, UnreachableError, make_plant
from ilcforce.plants.fivebar import FiveBarParams
from ilcforce.plants.serial2r import Serial2RParams
from ilcforce.simulate import SimulationSettings, force_axis
from ilcforce.task import Reference, Wall


class ConfigError(ValueError):
    """An invalid experiment configuration; the message is one line naming the bad field."""


@dataclass(frozen=True)
class ExperimentInfo:
    name: str = "paper"  # names the results folder results/<name>/
    description: str = "The paper's setup (SPEC defaults)"
    seed: int = 0  # root of every random draw: (seed, iteration) -> disturbance and noise
    iterations: int = 20  # number of iterations j = 0 .. iterations - 1

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise ValueError(f"experiment.seed must be >= 0, got {self.seed}")
        if self.iterations < 1:
            raise ValueError(f"experiment.iterations must be >= 1, got {self.iterations}")
        if not self.name or any(c in self.name for c in "/\\") or self.name.startswith("."):
            raise ValueError(f"experiment.name must be a plain folder name, got {self.name!r}")


@dataclass(frozen=True)
class Perturbation:
    """The true plant's parameter change (Section 4.1: m3 x 1.4 from j = 10); the nominal model never changes."""

    parameter: str = ""  # one of the plant model's parameter names; "" = the model's default (m3, or m2 for serial2r)
    factor: float = 1.4  # multiplier applied to the true plant
    from_iteration: int = 10  # first iteration with the changed plant

    def __post_init__(self) -> None:
        if not (math.isfinite(self.factor) and self.factor > 0):
            raise ValueError(f"plant.perturbation.factor must be finite and positive, got {self.factor!r}")
        if self.from_iteration < 0:
            raise ValueError(f"plant.perturbation.from_iteration must be >= 0, got {self.from_iteration}")


@dataclass(frozen=True)
class PlantConfig:
    """The robot (``model``), each model's nominal parameters, and the true plant's perturbation.

    Only the selected model's table is used; the other keeps its defaults.
    """

    model: str = "fivebar"  # a key of ilcforce.plants.MODELS
    fivebar: FiveBarParams = field(default_factory=FiveBarParams)  # SPEC section 1, Table 1
    serial2r: Serial2RParams = field(default_factory=Serial2RParams)  # SPEC section 8
    perturbation: Perturbation = field(default_factory=Perturbation)

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ValueError(f"plant.model must be one of {', '.join(MODELS)}, got {self.model!r}")
        names = tuple(f.name for f in dataclasses.fields(self.nominal()))
        p = self.perturbation
        if p.parameter == "":  # the model's default perturbation (SPEC sections 1 and 8)
            object.__setattr__(self, "perturbation", dataclasses.replace(p, parameter=MODELS[self.model][3]))
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


@dataclass(frozen=True)
class SurfaceGains:
    """Selection and sliding-surface gains of eqs. (6)-(8), shared by every method (erratum 2)."""

    selection: tuple[float, float] = (0.0, 1.0)  # s: S = diag(s) selects the force axis (y)
    lambda_p: tuple[float, float] = (2.0, 0.0)  # 1/s
    lambda_f1: tuple[float, float] = (0.0, 1e-3)  # m/(N s)
    lambda_f2: tuple[float, float] = (0.0, 1e-4)  # m/N

    def __post_init__(self) -> None:
        for name in ("selection", "lambda_p", "lambda_f1", "lambda_f2"):
            check_vector(f"surface.{name}", getattr(self, name), 2)
        force_axis(self.selection)


def _default_gains() -> dict[str, object]:
    return {name: spec.gains_class() for name, spec in REGISTRY.items()}


@dataclass(frozen=True)
class Config:
    """A whole experiment. ``gains`` maps each registered method name to its gains dataclass."""

    experiment: ExperimentInfo = field(default_factory=ExperimentInfo)
    plant: PlantConfig = field(default_factory=PlantConfig)
    wall: Wall = field(default_factory=Wall)
    reference: Reference = field(default_factory=Reference)
    simulation: SimulationSettings = field(default_factory=SimulationSettings)
    noise: NoiseModel = field(default_factory=NoiseModel)
    surface: SurfaceGains = field(default_factory=SurfaceGains)
    gains: dict = field(default_factory=_default_gains)

    @property
    def n_control(self) -> int:
        return self.simulation.n_control(self.reference.duration)

    @property
    def n_log(self) -> int:
        return self.simulation.n_log(self.reference.duration)

    def control_times(self) -> np.ndarray:
        return np.arange(self.n_control) * self.simulation.sample_time

    def reference_samples(self) -> np.ndarray:
        """(n_control, 12) reference on the control grid (``ilcforce.task`` layout)."""
        return self.reference.sample(self.control_times(), self.wall)

    def to_dict(self) -> dict:
        """Plain nested dict in the TOML layout (round-trips through :func:`config_from_dict`)."""
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
# building dataclasses from plain data, with one-line errors naming the field
# ------------------------------------------------------------------------------------------------

def _did_you_mean(key: str, options) -> str:
    close = difflib.get_close_matches(key, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _in_range(path: str, value, kind: type):
    valid = range_of(path, kind)
    if not valid.contains(value):
        raise ConfigError(f"{path} must be in {valid}, got {value!r}")
    return value


def _coerce(path: str, value, annotation):
    origin = typing.get_origin(annotation)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{path} must be a number, got {_short(value)}")
        try:
            value = float(value)
        except OverflowError:
            raise ConfigError(f"{path} must be finite, got {_short(value)}") from None
        if not math.isfinite(value):
            raise ConfigError(f"{path} must be finite, got {value!r}")
        return _in_range(path, value, float)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path} must be an integer, got {_short(value)}")
        return _in_range(path, value, int)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path} must be a string, got {_short(value)}")
        if len(value) > MAX_STRING or not value.replace("\n", " ").replace("\t", " ").isprintable():
            raise ConfigError(f"{path} must be at most {MAX_STRING} printable characters, got {_short(value)}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path} must be a list of numbers, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            items = [_coerce(f"{path}[{i}]", v, args[0]) for i, v in enumerate(value)]
        else:
            if len(value) != len(args):
                raise ConfigError(f"{path} must have {len(args)} entries, got {len(value)}")
            items = [_coerce(f"{path}[{i}]", v, a) for i, (v, a) in enumerate(zip(value, args))]
        return tuple(items)
    raise TypeError(f"unsupported annotation {annotation!r} at {path}")


def _short(value) -> str:
    """repr of a value, cut to 60 characters (a 400-digit number stays readable)."""
    text = repr(value) if not isinstance(value, int) or abs(value) < 10**40 else f"an integer with {len(str(abs(value)))} digits"
    return text if len(text) <= 60 else text[:57] + "..."


def _build(cls, data, path: str, base=None):
    """Instantiate dataclass ``cls`` from ``data`` (a dict), starting from ``base`` or defaults."""
    if not isinstance(data, dict):
        raise ConfigError(f"[{path}] must be a table, got {data!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            raise ConfigError(f"unknown key {path}.{key}{_did_you_mean(key, names)}")
        annotation = hints[key]
        if dataclasses.is_dataclass(annotation):
            kwargs[key] = _build(annotation, value, f"{path}.{key}", getattr(base, key) if base else None)
        else:
            kwargs[key] = _coerce(f"{path}.{key}", value, annotation)
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except ValueError as exc:
        msg = str(exc)
        raise ConfigError(msg if "." in msg.split(" ")[0] else f"{path}: {msg}") from None


def config_from_dict(data: dict) -> Config:
    """Build and validate a :class:`Config` from the TOML layout; raises :class:`ConfigError`."""
    if not isinstance(data, dict):
        raise ConfigError("the configuration must be a TOML table")
    sections = {f.name: f for f in dataclasses.fields(Config) if f.name != "gains"}
    default = Config()
    kwargs = {}
    gains = dict(default.gains)
    for key, value in data.items():
        if key in sections:
            kwargs[key] = _build(type(getattr(default, key)), value, key)
        elif key in REGISTRY:
            gains[key] = _build(REGISTRY[key].gains_class, value, key)
        else:
            raise ConfigError(f"unknown section [{key}]{_did_you_mean(key, [*sections, *REGISTRY])}")
    try:
        config = Config(**kwargs, gains=gains)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    _check_consistency(config)
    return config


def run_footprint(config: Config) -> tuple[int, int]:
    """(bytes of working memory, integrator steps) one iteration needs, estimated from the grid.

    Per control sample: the reference (12 floats), the learned memory (old and new, up to 2 x 16),
    the noise draws (about 10), the raw log before decimation (about 40): about 100 float64; plus two
    finished iterations' records (log and memory copies, about 56 each) waiting for or in the store's
    writes while the next iteration simulates (:mod:`ilcforce.pipeline`): about 212 float64.
    """
    sim = config.simulation
    n_control = config.reference.duration / sim.sample_time + 1
    return int(n_control * 212 * 8), int(n_control * sim.substeps)


def _check_consistency(config: Config) -> None:
    """Cross-field checks, all before any simulation starts (resources first: cheap to compute)."""
    if config.reference.duration <= 0:
        raise ConfigError(f"reference.duration must be positive, got {config.reference.duration}")
    needed, steps = run_footprint(config)
    if needed > MAX_RUN_BYTES:
        raise ConfigError(f"a run would need about {needed / 1024**3:.3g} GiB of memory per iteration "
                          f"(reference.duration / simulation.sample_time = "
                          f"{config.reference.duration / config.simulation.sample_time:.3g} samples); the limit is "
                          f"{MAX_RUN_BYTES / 1024**3:g} GiB")
    if steps > MAX_STEPS_PER_ITERATION:
        raise ConfigError(f"an iteration would take {steps:.3g} integrator steps (samples x simulation.substeps); "
                          f"the limit is {MAX_STEPS_PER_ITERATION:.0e}")
    try:
        config.n_log  # Ts divides the horizon, log_every divides the step count
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    # the reference must stay in the reachable, elbows-out workspace of the nominal and true plants
    t = np.linspace(0.0, config.reference.duration, 401)
    poses = config.reference.sample(t, config.wall)[:, 0:2]
    start = np.asarray(config.simulation.initial_position)
    for label, params in (("nominal", config.plant.nominal()),
                          ("perturbed", config.plant.true_plant(config.plant.perturbation.from_iteration))):
        robot = make_plant(params)
        for pos in (start, *poses):
            try:
                robot.inverse_kinematics(pos)
            except UnreachableError:
                where = "simulation.initial_position" if pos is start else "the reference"
                raise ConfigError(f"{where} leaves the reachable workspace of the {label} plant at "
                                  f"({pos[0]:.4g}, {pos[1]:.4g}) m") from None


def default_config() -> Config:
    """The paper's setup (SPEC defaults)."""
    return config_from_dict({})


def _set_path(data: dict, dotted: str, value) -> None:
    keys = dotted.split(".")
    node = data
    for key in keys[:-1]:
        node = node.setdefault(key, {})
        if not isinstance(node, dict):
            raise ConfigError(f"--set {dotted}: {key} is not a table")
    node[keys[-1]] = value


def parse_override(text: str) -> tuple[str, object]:
    """``"c3.eta=2"`` -> ("c3.eta", 2); the value is read as TOML, else taken as a string."""
    if "=" not in text:
        raise ConfigError(f"--set expects KEY=VALUE (e.g. c3.eta=2), got {text!r}")
    key, raw = (part.strip() for part in text.split("=", 1))
    if not key:
        raise ConfigError(f"--set expects KEY=VALUE, got {text!r}")
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def load_config(path: Path | str | None = None, overrides: dict[str, object] | None = None) -> Config:
    """Load ``path`` (None: the paper's setup), apply dotted ``overrides``, validate everything."""
    data: dict = {}
    if path is not None:
        path = Path(path)
        if not path.exists():
            raise ConfigError(f"config file {path} does not exist")
        if path.is_dir():
            raise ConfigError(f"config file {path} is a directory, not a TOML file")
        if not path.is_file():
            raise ConfigError(f"config file {path} is not a regular file (a FIFO or device?)")
        try:
            text = path.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"config file {path} cannot be read: {exc}") from None
        if not text.strip():
            raise ConfigError(f"config file {path} is empty")
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None
    for key, value in (overrides or {}).items():
        _set_path(data, key, value)
    try:
        return config_from_dict(data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}" if path is not None else str(exc)) from None


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
