"""Loading an experiment configuration: TOML file plus ``--set`` overrides -> a validated :class:`Config`.

One loader (:func:`load_config`) builds and validates every field of the tree in
:mod:`ilcforce.config` (the TOML layout is described there) and names the bad one in a one-line
:class:`~ilcforce.config.ConfigError`: types and ranges per field (:mod:`ilcforce.config_ranges`),
then cross-field checks (resources, grid, reachable workspace) before any simulation starts. With
no file, :func:`default_config` is the paper's setup as docs/model.md decides it; ``experiments/paper.toml``
spells the same values out and a test pins that the two agree.
"""

from __future__ import annotations

import copy
import dataclasses
import datetime
import difflib
import math
import os
import tomllib
import typing
from pathlib import Path

import numpy as np

from ilcforce.config import Config, ConfigError
from ilcforce.config_ranges import MAX_RUN_BYTES, MAX_STEPS_PER_ITERATION, MAX_STRING, range_of
from ilcforce.controllers import REGISTRY
from ilcforce.controllers.nd import check_widths
from ilcforce.plants import UnreachableError, make_plant
from ilcforce.tomlfile import parse_toml, read_toml, resolve_toml
from ilcforce.config_ranges import experiment_name_problem


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
            raise ConfigError(f"{path} must be a number, got {shown(value)}")
        try:
            value = float(value)
        except OverflowError:
            raise ConfigError(f"{path} must be finite, got {shown(value)}") from None
        if not math.isfinite(value):
            raise ConfigError(f"{path} must be finite, got {value!r}")
        return _in_range(path, value, float)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{path} must be an integer, got {shown(value)}")
        return _in_range(path, value, int)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path} must be a string, got {shown(value)}")
        if len(value) > MAX_STRING or not value.replace("\n", " ").replace("\t", " ").isprintable():
            raise ConfigError(f"{path} must be at most {MAX_STRING} printable characters, got {shown(value)}")
        return value
    if origin is tuple:
        args = typing.get_args(annotation)
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path} must be a list of numbers, got {shown(value)}")
        if len(args) == 2 and args[1] is Ellipsis:
            items = [_coerce(f"{path}[{i}]", v, args[0]) for i, v in enumerate(value)]
        else:
            if len(value) != len(args):
                raise ConfigError(f"{path} must have {len(args)} entries, got {len(value)}")
            items = [_coerce(f"{path}[{i}]", v, a) for i, (v, a) in enumerate(zip(value, args))]
        return tuple(items)
    raise TypeError(f"unsupported annotation {annotation!r} at {path}")


def shown(value) -> str:
    """repr of a value, cut to 60 characters (a 400-digit number stays readable); a TOML date or
    time as the user wrote it, not as Python's repr."""
    if isinstance(value, (datetime.date, datetime.time)):  # datetime.datetime is a date too
        kind = ("a date-time" if isinstance(value, datetime.datetime)
                else "a date" if isinstance(value, datetime.date) else "a time")
        return f"{kind} ({value.isoformat()})"
    if isinstance(value, list):
        text = "[" + ", ".join(shown(item) for item in value[:20]) + (", ..." if len(value) > 20 else "") + "]"
        return text if len(text) <= 60 else text[:57] + "..."
    text = repr(value) if not isinstance(value, int) or abs(value) < 10**40 else f"an integer with {len(str(abs(value)))} digits"
    return text if len(text) <= 60 else text[:57] + "..."


def _build(cls, data, path: str, base=None):
    """Instantiate dataclass ``cls`` from ``data`` (a dict), starting from ``base`` or defaults."""
    if not isinstance(data, dict):
        raise ConfigError(f"[{path}] must be a table, got {shown(data)}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    kwargs = {}
    for key, value in data.items():
        if key not in names:
            where = f"{path}.{key}" if key.strip() == key and key.isprintable() else repr(f"{path}.{key}")
            raise ConfigError(f"unknown key {where}{_did_you_mean(key.strip(), names)}")  # repr: 'eta ' shows its space
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


def method_parent(method: str) -> str | None:
    """The registered method whose gains ``method``'s gains extend (c3-leak -> c3), or None.

    A method family is read from the gains classes themselves: C3-leak's gains are C3's plus two
    fields, so C3-leak *is* C3 with leakage, and a key of C3's that C3-leak shares means the same law.
    """
    mine = REGISTRY[method].gains_class
    parents = [name for name, spec in REGISTRY.items()
               if name != method and spec.gains_class is not mine and issubclass(mine, spec.gains_class)]
    return parents[0] if parents else None


def inherited_gains(data: dict) -> dict[str, dict]:
    """The tables of the methods that inherit a key set in their parent's table.

    The rule (one for every method family): a key set in a method's table (``[c3]``, or ``--set
    c3.psi_acceleration=desired``) reaches every method whose gains extend that method's and have the
    key (``[c3-leak]``), unless that method's own table sets it. Without the rule, a setting meant
    for the C3 law reached C3 alone and C3-leak silently kept the default (its measured-acceleration
    Psi diverged at j = 0 in an experiment written for the desired one). Returns method -> its table
    with the inherited keys filled in (only methods that inherit something). A gains class may name
    keys it decides for itself (``own_keys``, e.g. C3-robust's ``psi_acceleration``): those are never
    inherited.
    """
    out: dict[str, dict] = {}
    for method in REGISTRY:
        parent = method_parent(method)
        if parent is None or not isinstance(data.get(parent), dict):
            continue
        own = data.get(method, {})
        if not isinstance(own, dict):
            continue  # not a table: the method's own build names the fault
        gains_class = REGISTRY[method].gains_class
        names = {f.name for f in dataclasses.fields(gains_class)} - set(getattr(gains_class, "own_keys", ()))
        shared = {k: v for k, v in data[parent].items() if k in names and k not in own}
        if shared:
            out[method] = {**shared, **own}
    return out


def config_from_dict(data: dict) -> Config:
    """Build and validate a :class:`Config` from the TOML layout; raises :class:`ConfigError`."""
    if not isinstance(data, dict):
        raise ConfigError("the configuration must be a TOML table")
    sections = {f.name: f for f in dataclasses.fields(Config) if f.name != "gains"}
    default = Config()
    kwargs = {}
    gains = dict(default.gains)
    inherited = inherited_gains(data)
    for key, value in data.items():
        if key in sections:
            kwargs[key] = _build(type(getattr(default, key)), value, key)
        elif key in REGISTRY:
            if key not in inherited:  # built below with what it inherits (its own table alone may be incomplete)
                gains[key] = _build(REGISTRY[key].gains_class, value, key)
        else:
            if key == "study":  # a study file given where an experiment file belongs
                raise ConfigError("[study] is a study file's table, not an experiment's: run a study file with "
                                  "`ilcforce study`")
            raise ConfigError(f"unknown section [{key}]{_did_you_mean(key, [*sections, *REGISTRY])}")
    for key, value in inherited.items():
        gains[key] = _build(REGISTRY[key].gains_class, value, key)
    try:
        config = Config(**kwargs, gains=gains)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    _check_consistency(config)
    for method in REGISTRY:  # a method's table, as given (or inherited), is written for this task's axes
        if method in data or method in inherited:
            try:
                check_widths(method, config.gains[method], config.dimension)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
    return config


def run_footprint(config: Config) -> tuple[int, int]:
    """(bytes of working memory, integrator steps) one iteration needs, estimated from the grid.

    Per control sample: the reference (12 floats), the learned memory (old and new, up to 2 x 16),
    the noise draws (about 10), the raw log before decimation (about 40): about 100 float64; plus two
    finished iterations' records (log signals and memory, about 56 each) waiting for or in the store's
    writes while the next iteration simulates (:mod:`ilcforce.pipeline`): about 212 float64. (A small
    run keeps up to eight records waiting, within ``ilcforce.experiment.RECORDS_AHEAD_BYTES``; a run near the
    limit keeps one, as counted here.)
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
    # the task has as many axes as the robot has joints (docs/model.md#n-dof)
    n = config.dimension
    nominal_robot = make_plant(config.plant.nominal())
    robot_n = nominal_robot.dimension
    if robot_n != n:
        raise ConfigError(f"the robot of plant.model = {config.plant.model!r} has {robot_n} joints, so its task needs "
                          f"{robot_n} axes; surface.selection has {n} entries")
    if len(config.simulation.initial_position) != n:
        raise ConfigError(f"simulation.initial_position must have {n} entries (the task's axes), got "
                          f"{len(config.simulation.initial_position)}")
    try:
        frame = config.wall.frame(n)
        nominal_robot.check_frame(frame)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    # the reference must stay in the reachable workspace (the working mode) of the nominal and true plants
    t = np.linspace(0.0, config.reference.duration, 401)
    poses = config.reference.sample(t, config.wall, n)[:, 0:n]
    start = np.asarray(config.simulation.initial_position)
    for label, params in (("nominal", config.plant.nominal()),
                          ("perturbed", config.plant.true_plant(config.plant.perturbation.from_iteration))):
        robot = make_plant(params)
        for pos in (start, *poses):
            try:
                robot.inverse_kinematics(frame.T @ pos)  # world P = R^T X
            except UnreachableError:
                where = "simulation.initial_position" if pos is start else "the reference"
                shown_pos = ", ".join(f"{v:.4g}" for v in pos)
                raise ConfigError(f"{where} leaves the reachable workspace of the {label} plant at "
                                  f"({shown_pos}) m") from None


def default_config() -> Config:
    """The paper's setup (the defaults of docs/model.md)."""
    return config_from_dict({})


class _NotATable(ConfigError):
    def __init__(self, message: str, *, from_file: bool) -> None:
        super().__init__(message)
        self.from_file = from_file


def _set_path(data: dict, dotted: str, value, file_data: dict) -> None:
    """Set ``dotted`` in ``data``; a value where a table belongs is named, with the file's name when
    it is the file's (``file_data``: the file as read, None without a file) and without when an
    earlier override put it there."""
    keys = dotted.split(".")
    node, in_file = data, file_data
    for depth, key in enumerate(keys[:-1]):
        node = node.setdefault(key, {})
        in_file = in_file.get(key) if isinstance(in_file, dict) else None
        if not isinstance(node, dict):
            above = ".".join(keys[:depth + 1])
            message = f"{above} = {shown(node)} is not a table ([{above}]), so {dotted} cannot be set"
            raise _NotATable(message, from_file=in_file is not None and not isinstance(in_file, dict))
    node[keys[-1]] = value


def _from_overrides(message: str, overrides: dict) -> bool:
    """Whether a validation message names an overridden key (the fault is not the file's)."""
    return any(message.startswith(f"{key} ") for key in overrides)


def parse_override(text: str) -> tuple[str, object]:
    """``"c3.eta=2"`` -> ("c3.eta", 2); the value is read as TOML, else taken as a string."""
    if "=" not in text:
        raise ConfigError(f"--set expects KEY=VALUE (e.g. c3.eta=2), got {text!r}")
    key, raw = (part.strip() for part in text.split("=", 1))
    if not key:
        raise ConfigError(f"--set expects KEY=VALUE, got {text!r}")
    try:
        value = parse_toml(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:  # not a TOML value (or a 5000-digit integer, or nested too deeply)
        value = raw
    return key, value


def command_overrides(sets=(), seed: int | None = None, iters: int | None = None) -> dict[str, object]:
    """The overrides of a command line's ``--set`` items, ``--seed`` and ``--iters``; ConfigError for
    a negative seed, fewer than one iteration, or a key given both ways (:data:`OWN_OPTION`).

    ``--set experiment.iterations`` is refused in favour of ``--iters``: the number of iterations never
    makes a variant (iteration j is the same whether 10 or 20 are run, so such a run is the
    experiment's own store), unlike every other ``--set`` key, and two ways to give it could disagree."""
    overrides = dict(parse_override(s) for s in (sets or ()))
    if "experiment.iterations" in overrides:
        raise ConfigError(f"--set experiment.iterations={_plain(overrides['experiment.iterations'])}: give the "
                          "number of iterations with --iters (it is not a variant: the run is the experiment's own)")
    if seed is not None and "experiment.seed" in overrides:
        raise ConfigError(f"--seed {seed} and --set experiment.seed={_plain(overrides['experiment.seed'])} both "
                          "give the seed; give it once, with --seed")
    if seed is not None:
        if seed < 0:
            raise ConfigError(f"--seed must be >= 0, got {seed}")
        overrides["experiment.seed"] = seed
    if iters is not None:
        if iters < 1:
            raise ConfigError(f"--iters must be >= 1, got {iters}")
        overrides["experiment.iterations"] = iters
    return overrides


def _name_after_file(data: dict, path: Path) -> None:
    """An experiment file without ``experiment.name`` (or description) is named after the file: with
    the paper's name its runs went to the paper's own results folder (results/paper/)."""
    experiment = data.setdefault("experiment", {})
    if not isinstance(experiment, dict):  # not a table: config_from_dict names the fault
        return
    if "name" not in experiment:
        problem = experiment_name_problem(path.stem)  # the one rule experiment.name itself follows
        if problem:
            raise ConfigError(f"{path}: experiment.name is not set and the file's name {path.stem!r} {problem}; "
                              "set experiment.name")
        experiment["name"] = path.stem
    experiment.setdefault("description", f"experiment file {path.name}")


#: Overrides that do not make a run different from its experiment's (they are not noted in its description).
_NOT_A_VARIANT = ("experiment.name", "experiment.description", "experiment.iterations")


def _plain(value):
    """A configuration value as it reads in a description: 2.0 -> 2, [1.0, 2.0] -> [1, 2]."""
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e15:
        return str(int(value))
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_plain(v) for v in value) + "]"
    return str(value)


def _noted(config: Config, base: dict, overrides: dict[str, object]) -> Config:
    """``config`` whose description also says what the overrides changed against the experiment
    (``base``: the file's data, or {} for the paper's setup), e.g. "..., with c3.eta = 2 (was 5)".
    An overridden description, or overrides that change nothing, leave it as it is."""
    if "experiment.description" in overrides:
        return config
    keys = [key for key in overrides if key not in _NOT_A_VARIANT]
    if not keys:
        return config
    try:
        before = _flat(config_from_dict(base).to_dict())
    except ConfigError:  # the file alone is not valid (an override completes it): no "was"
        before = {}
    after = _flat(config.to_dict())
    changes = [f"{key} = {_plain(after[key])}" + (f" (was {_plain(before[key])})" if key in before else "")
               for key in sorted(keys) if key in after and before.get(key, object()) != after[key]]
    if not changes:
        return config
    text = f"{config.experiment.description}, with {', '.join(changes)}"
    if len(text) > MAX_STRING:  # as long as a description may be, so that the stored config reads back
        text = text[:MAX_STRING - 3] + "..."
    experiment = dataclasses.replace(config.experiment, description=text)
    return dataclasses.replace(config, experiment=experiment)


def _flat(tree: dict, prefix: str = "") -> dict[str, object]:
    out: dict[str, object] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _path_keys() -> set[str]:
    """``plant.<model>.<key>`` of every robot parameter that names a file (a model file's ``path``)."""
    from ilcforce.plants import MODELS, params_class

    return {f"plant.{model}.{key}" for model in MODELS for key in getattr(params_class(model), "path_keys", ())}


def _is_path_key(dotted: str) -> bool:
    return dotted.startswith("plant.") and dotted in _path_keys()


def _absolute_path(value, folder: Path):
    """A relative file path read relative to ``folder`` (the experiment file's, or the working
    directory for ``--set``), made absolute so that the configuration (and a store's copy of it)
    names the same file from anywhere; a bare name of a shipped model file (``serial2r.xml``) that is
    not in ``folder`` is the shipped one. Anything but a non-empty string is left for validation."""
    if not isinstance(value, str) or not value or "\0" in value:
        return value
    candidate = Path(value).expanduser()
    if candidate.is_absolute():
        return str(candidate)
    found = folder / candidate
    if not found.exists() and len(candidate.parts) == 1:
        from ilcforce.plants.model_file import resolve_model

        shipped = resolve_model(candidate)
        found = shipped if shipped.is_absolute() else found
    return str(found.absolute())


def _absolute_paths(data: dict, folder: Path) -> None:
    for dotted in _path_keys():
        _, model, key = dotted.split(".")
        plant = data.get("plant")
        table = plant.get(model) if isinstance(plant, dict) else None
        if isinstance(table, dict) and key in table:
            table[key] = _absolute_path(table[key], folder)


def relative_paths(data: dict, folder: Path) -> None:
    """The inverse of reading a file's paths (:func:`_absolute_paths`): every absolute model-file path in a
    configuration's ``data`` rewritten relative to ``folder``, where an experiment file holding ``data`` is
    written, so that the file names the same model from any checkout it is copied with (``ilcforce tune -o``)."""
    for dotted in _path_keys():
        _, model, key = dotted.split(".")
        plant = data.get("plant")
        table = plant.get(model) if isinstance(plant, dict) else None
        if isinstance(table, dict) and isinstance(table.get(key), str) and os.path.isabs(table[key]):
            table[key] = Path(os.path.relpath(os.path.normpath(table[key]), os.path.abspath(folder))).as_posix()


def load_config(path: Path | str | None = None, overrides: dict[str, object] | None = None, *,
                note_overrides: bool = True) -> Config:
    """Load ``path`` (None: the paper's setup; a bare name such as ``"serial2r"``: the shipped file), apply dotted ``overrides``, validate everything.

    With ``note_overrides`` (the default) the experiment's description also says what the overrides
    changed (``"The paper's setup (...), with c3.eta = 2 (was 5)"``), so a stored run says what it
    ran; ``experiment.name``, ``experiment.iterations`` and an overridden description are not noted.
    """
    data: dict = {}
    file_data: dict = {}
    overrides = overrides or {}
    if path is not None:
        path = resolve_toml(path)  # a shipped experiment by its bare name: -c serial2r
        data, _ = read_toml(path, "config file", ConfigError)
        file_data = copy.deepcopy(data)
        _name_after_file(data, path)
    _absolute_paths(data, path.parent if path is not None else Path.cwd())
    overrides = {key: _absolute_path(value, Path.cwd()) if _is_path_key(key) else value
                 for key, value in overrides.items()}
    base = copy.deepcopy(data) if note_overrides and overrides else None
    for key, value in overrides.items():
        try:
            _set_path(data, key, value, file_data)
        except _NotATable as exc:  # a value where a table belongs: the file's (experiment = 3) or an override's
            raise ConfigError(f"{path}: {exc}" if exc.from_file else str(exc)) from None
    try:
        config = config_from_dict(data)
    except ConfigError as exc:  # the file is named unless the message names an overridden key
        blame = path is not None and not _from_overrides(str(exc), overrides)
        raise ConfigError(f"{path}: {exc}" if blame else str(exc)) from None
    return _noted(config, base, overrides) if base is not None else config
