"""The study file: what to run, validated in full before any cell runs.

A study is a set of **settings** (the full factorial of ``[study.sweep]``, or an explicit list
``[[study.settings]]``, or the list times the sweep; each on top of the experiment file and
``[study.set]``) times **seeds** times **methods**. One **cell** is (setting,
seed, method): all iterations of one method, i.e. exactly what ``ilcforce simulate --seed S
--method M`` with the setting's overrides runs.

File format (TOML)::

    [study]
    name = "ts-sweep"                        # results/studies/<name>.h5; a plain file name
    description = "..."                      # optional, shown in the report
    experiment = "paper.toml"                # optional; relative to the study file (then to the
                                             #   working directory); the paper's setup if absent
    methods = ["c1", "c2", "c3"]             # optional; every registered method if absent
    seeds = "0-99"                           # "a-b" (inclusive) or a list of integers >= 0
    [study.set]                              # fixed overrides, exactly as --set
    "experiment.iterations" = 20
    [study.sweep]                            # full factorial grid; the first key varies slowest
    "simulation.sample_time" = [1e-4, 2.5e-4, 5e-4, 1e-3]

or, instead of (or besides) the sweep, an explicit list of named settings
(:mod:`ilcforce.study.settings_list`)::

    [[study.settings]]
    label = "disturbance only"               # optional, unique; shown in the report and the table
    "noise.encoder" = 0.0                    # overrides on top of the experiment and [study.set]
    "noise.force_sensor" = 0.0
    [[study.settings]]
    label = "all"                            # no keys: the experiment as it is

Entries may name different keys; the setting columns are the union of the keys, a setting that
leaves a key alone carrying the experiment's value. With a sweep too, every listed setting is
combined with every sweep point (the listed setting varies slowest).

``experiment.seed`` may not appear in ``set``, ``sweep`` or a listed setting: ``seeds`` owns it.
Every problem raises :class:`StudyError` with one line naming the key (and the setting).
"""

from __future__ import annotations

import dataclasses
import difflib
import itertools
import math
import re
from dataclasses import dataclass
from pathlib import Path

from ilcforce.config import Config, ConfigError
from ilcforce.config_load import load_config, shown
from ilcforce.store.schema import STUDY_NAME
from ilcforce.study import settings_list
from ilcforce.tomlfile import read_toml


class StudyError(ValueError):
    """An invalid study file or study request; the message is one line."""


#: Keys allowed in the [study] table.
STUDY_KEYS = ("name", "description", "experiment", "methods", "seeds", "set", "sweep", "settings")
#: A study name becomes a file name under results/studies/: no separators, no leading dot.
_NAME = STUDY_NAME
#: Seeds allowed per study (a guard against "0-99999999999" typos, not a limit of the method).
MAX_SEEDS = 100_000
#: Cells allowed per study.
MAX_CELLS = 1_000_000


@dataclass(frozen=True)
class Setting:
    """One setting of the study: a point of the sweep, a listed setting, or a listed setting at a
    point of the sweep.

    Attributes
    ----------
    index : int
        Position in the study's settings (0-based; listed setting slowest, then the first sweep key).
    values : tuple of (key, value)
        The setting columns and their values here: the listed settings' keys (every one of the
        union, the experiment's value where this setting leaves the key alone), then the swept keys
        (empty without either).
    config : Config
        The resolved, validated configuration; its ``experiment.seed`` is 0 and is replaced per cell.
    listed : str or None
        The label of the listed setting (``[[study.settings]]``) this setting comes from; None
        without a settings list.
    sweep_values : tuple of (key, value)
        The swept keys and their values alone.
    """

    index: int
    values: tuple[tuple[str, object], ...]
    config: Config
    listed: str | None = None
    sweep_values: tuple[tuple[str, object], ...] = ()

    def label(self) -> str:
        """The listed label (with the sweep point, if any), ``"simulation.sample_time=0.001"``, or ``"base"``."""
        sweep = ", ".join(f"{k}={v!r}" for k, v in self.sweep_values)
        if self.listed is not None:
            return f"{self.listed}; {sweep}" if sweep else self.listed
        return ", ".join(f"{k}={v!r}" for k, v in self.values) or "base"


@dataclass(frozen=True)
class Cell:
    """One unit of work: all iterations of ``method`` for ``seed`` at setting ``setting``."""

    setting: int
    seed: int
    method: str

    @property
    def key(self) -> str:
        """Stable text key, also the cell's record name in the study store."""
        return f"{self.setting}-{self.seed}-{self.method}"


@dataclass(frozen=True)
class Study:
    """A parsed and validated study file."""

    name: str
    description: str
    source: str  # the study file's text (provenance)
    path: Path | None  # the study file (None for a study built in code)
    experiment: Path | None  # the experiment file the settings start from (None: the paper's setup)
    methods: tuple[str, ...]
    seeds: tuple[int, ...]
    fixed: dict  # [study.set]: dotted key -> value
    sweep: dict  # [study.sweep]: dotted key -> tuple of values, in file order
    settings: tuple[Setting, ...]
    listed: tuple = ()  # [[study.settings]]: ListedSetting entries, in file order (empty without)

    def cells(self) -> list[Cell]:
        """Every cell, setting-major, then seed, then method."""
        return [Cell(s.index, seed, m) for s in self.settings for seed in self.seeds for m in self.methods]

    def cell_config(self, cell: Cell) -> Config:
        """The resolved configuration of ``cell`` (its setting's, with ``experiment.seed`` set)."""
        config = self.settings[cell.setting].config
        return dataclasses.replace(config, experiment=dataclasses.replace(config.experiment, seed=cell.seed))

    def definition(self) -> dict:
        """What identifies the study's settings (stored; a rerun must match it).

        ``sweep_keys`` names the setting columns of the tidy table (for a settings list: the union
        of its keys, then the swept keys); ``labels`` is there only with a settings list."""
        definition = {"name": self.name, "sweep_keys": self.columns(),
                      "settings": [s.config.to_json() for s in self.settings]}
        if self.listed:
            definition["labels"] = [s.label() for s in self.settings]
        return definition

    def columns(self) -> list[str]:
        """The setting columns: the listed settings' keys (union), then the swept keys."""
        return [*settings_list.column_keys(self.listed), *self.sweep]


def parse_seeds(value) -> tuple[int, ...]:
    """``"a-b"`` (inclusive, a <= b) or a list of distinct integers >= 0 -> sorted tuple."""
    if isinstance(value, str):
        match = re.fullmatch(r"\s*(\d+)\s*-\s*(\d+)\s*", value)
        if not match:
            raise StudyError(f"study.seeds must be a range \"a-b\" of integers >= 0 or a list of integers, got {shown(value)}")
        first, last = int(match.group(1)), int(match.group(2))
        if first > last:
            raise StudyError(f"study.seeds range {value!r} is empty: {first} > {last}")
        if last - first + 1 > MAX_SEEDS:
            raise StudyError(f"study.seeds {value!r} asks for {last - first + 1} seeds; at most {MAX_SEEDS}")
        return tuple(range(first, last + 1))
    if isinstance(value, list):
        if not value:
            raise StudyError("study.seeds is an empty list")
        for item in value:
            if isinstance(item, bool) or not isinstance(item, int):
                raise StudyError(f"study.seeds must hold integers, got {shown(item)}")
            if item < 0:
                raise StudyError(f"study.seeds must be >= 0, got {item}")
        if len(set(value)) != len(value):
            dup = next(v for v in value if value.count(v) > 1)
            raise StudyError(f"study.seeds lists seed {dup} twice")
        if len(value) > MAX_SEEDS:
            raise StudyError(f"study.seeds lists {len(value)} seeds; at most {MAX_SEEDS}")
        return tuple(sorted(value))
    raise StudyError(f"study.seeds must be a range \"a-b\" or a list of integers, got {shown(value)}")


def _check_name(name) -> str:
    if not isinstance(name, str) or not name:
        raise StudyError(f"study.name must be a non-empty string, got {shown(name)}")
    if not _NAME.fullmatch(name) or name in (".", ".."):
        escapes = "/" in name or "\\" in name or name.startswith(".")
        why = "it would escape the results folder" if escapes else "it names the study's store file"
        raise StudyError(f"study.name {name!r} is not a plain file name (letters, digits, '.', '_', '-'; "
                         f"no '/' or leading '.'): {why}")
    return name


def _check_methods(value) -> tuple[str, ...]:
    from ilcforce.controllers import REGISTRY, MethodNameError, canonical_method

    if value is None:
        return tuple(REGISTRY)
    if not isinstance(value, list) or not value:
        raise StudyError(f"study.methods must be a non-empty list of method names, got {shown(value)}")
    names = []
    for item in value:
        try:
            name = canonical_method(item)  # any case, stored under the registry's name
        except MethodNameError as exc:
            raise StudyError(f"study.methods: {exc}") from None
        if name in names:
            raise StudyError(f"study.methods lists {name!r} twice")
        names.append(name)
    return tuple(names)


def _same_value(value) -> tuple:
    """A sweep value's identity: 5 and 5.0 are one value (the same setting twice), and so are
    [1, 2] and [1.0, 2.0]; True is not 1."""
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return ("number", value)  # == and hash take 5 == 5.0 exactly (no float(): 2**53 + 1, 400 digits)
    if isinstance(value, list):
        return ("list", tuple(_same_value(v) for v in value))
    return ("other", repr(value))


def _check_table(name: str, value) -> dict:
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise StudyError(f"study.{name} must be a table of \"section.key\" = value, got {shown(value)}")
    for key in value:
        if isinstance(value[key], dict):
            raise StudyError(f"study.{name}: write keys as quoted dotted names, e.g. \"{key}.x\" = ..., "
                             f"not a [study.{name}.{key}] table")
        if key == "experiment.seed":
            raise StudyError(f"study.{name}: experiment.seed is set by study.seeds")
    return dict(value)


def _resolve_experiment(value, study_path: Path | None) -> Path | None:
    if value is None:
        return None
    if not isinstance(value, str) or not value:
        raise StudyError(f"study.experiment must be a path to an experiment TOML file, got {shown(value)}")
    candidates = []
    if study_path is not None and not Path(value).is_absolute():
        candidates.append(study_path.parent / value)
    candidates.append(Path(value))
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    for candidate in candidates:  # something is there, but not a file: say what (as for any TOML file)
        if candidate.exists() or candidate.is_symlink():
            try:
                read_toml(candidate, "experiment file", StudyError)
            except StudyError as exc:
                raise StudyError(f"study.experiment: {exc}") from None
    tried = " or ".join(str(c) for c in dict.fromkeys(candidates))
    raise StudyError(f"study.experiment: no experiment file {tried}")


def _format_value(value) -> str:
    return repr(value)


def build_study(data: dict, *, source: str = "", path: Path | None = None) -> Study:
    """Validate a parsed study file (the whole TOML document) and resolve every setting."""
    if not isinstance(data, dict) or "study" not in data:
        raise StudyError("a study file needs a [study] table with at least name and seeds, e.g. [study] name = \"s\" seeds = \"0-9\"")
    extra = [k for k in data if k != "study"]
    if extra:
        raise StudyError(f"unknown top-level table [{extra[0]}] in a study file; only [study] (with "
                         "[study.set], [study.sweep] and [[study.settings]]) is read")
    table = data["study"]
    if not isinstance(table, dict):
        raise StudyError("[study] must be a table")
    for key in table:
        if key not in STUDY_KEYS:
            close = difflib.get_close_matches(key, STUDY_KEYS, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise StudyError(f"unknown key study.{key}{hint}")
    if "name" not in table:
        raise StudyError("study.name is missing")
    if "seeds" not in table:
        raise StudyError("study.seeds is missing (e.g. seeds = \"0-99\")")
    name = _check_name(table["name"])
    description = table.get("description", "")
    if not isinstance(description, str):
        raise StudyError(f"study.description must be a string, got {shown(description)}")
    methods = _check_methods(table.get("methods"))
    given = "methods" in table
    seeds = parse_seeds(table["seeds"])
    fixed = _check_table("set", table.get("set"))
    sweep_raw = _check_table("sweep", table.get("sweep"))
    sweep: dict[str, tuple] = {}
    for key, values in sweep_raw.items():
        if not isinstance(values, list):
            raise StudyError(f"study.sweep.\"{key}\" must be a list of values, got {shown(values)}")
        if not values:
            raise StudyError(f"study.sweep.\"{key}\" is an empty list")
        if len(set(map(_same_value, values))) != len(values):
            raise StudyError(f"study.sweep.\"{key}\" lists a value twice")
        if key in fixed:
            raise StudyError(f"study: {key} is both in [study.set] and [study.sweep]")
        sweep[key] = tuple(values)
    listed = ()
    if "settings" in table:
        try:
            listed = settings_list.parse_settings_list(table["settings"], fixed=fixed, sweep=sweep)
        except settings_list.SettingsListError as exc:
            raise StudyError(str(exc)) from None
    n_settings = (math.prod(len(v) for v in sweep.values()) if sweep else 1) * max(1, len(listed))
    if n_settings * len(seeds) * len(methods) > MAX_CELLS:
        raise StudyError(f"study has {n_settings * len(seeds) * len(methods)} cells; at most {MAX_CELLS}")
    experiment = _resolve_experiment(table.get("experiment"), path)
    settings = _settings(experiment, fixed, sweep, listed)
    # every seed must be valid for the configuration (e.g. ranges the loader enforces)
    for seed in {seeds[0], seeds[-1]}:
        try:
            first = load_config(experiment, {**fixed, **settings[0][1], "experiment.seed": seed})
        except ConfigError as exc:
            raise StudyError(f"study.seeds: {exc}") from None
    # a tuned experiment's withheld methods (no stable gains under its cap) and the methods its tuning did not
    # search (registered after it ran) are left out of the default list, and refused when named
    for method in methods if given else ():
        if (refusal := first.tuning.refusal(method)) is not None:
            raise StudyError(f"study.methods: {refusal}")
    methods = tuple(m for m in methods if first.tuning.refusal(m) is None)
    if not methods:
        raise StudyError("study.methods: every method is withheld by the tuned experiment ([tuning] withheld) "
                         "or was not tuned by it ([tuning] methods)")
    return Study(name=name, description=description, source=source, path=path, experiment=experiment,
                 methods=methods, seeds=seeds, fixed=fixed, sweep=sweep,
                 settings=tuple(setting for setting, _overrides in settings), listed=listed)


def _load(experiment: Path | None, overrides: dict, where: str) -> Config:
    try:
        # a setting is described by its own label and values (and a study store compares settings by
        # their whole configuration), so its description stays the experiment file's
        return load_config(experiment, {**overrides, "experiment.seed": 0}, note_overrides=False)
    except ConfigError as exc:
        if experiment is not None:  # the experiment file's own fault (the same one alone) is not the setting's
            try:
                load_config(experiment)
            except ConfigError as own:
                if str(own) == str(exc):
                    raise StudyError(f"study.experiment: {own}") from None
        raise StudyError(f"{where}: {exc}") from None


def _settings(experiment: Path | None, fixed: dict, sweep: dict,
              listed: tuple) -> list[tuple[Setting, dict]]:
    """Every setting (listed setting slowest, then the sweep grid), resolved and validated, with the
    overrides it was loaded from."""
    columns = settings_list.column_keys(listed)
    bases: list[tuple[object, dict]] = [(None, {})]
    if listed:
        bases, seen = [], {}
        for entry in listed:
            config = _load(experiment, {**fixed, **entry.overrides}, entry.where())
            text = config.to_json()
            if text in seen:
                raise StudyError(f"{entry.where()} resolves to the same configuration as {seen[text].where()}")
            seen[text] = entry
            bases.append((entry, entry.overrides))
    out: list[tuple[Setting, dict]] = []
    for entry, base in bases:
        grid = itertools.product(*sweep.values()) if sweep else [()]
        for point in grid:
            index = len(out)
            swept = tuple(zip(sweep, point))
            overrides = {**fixed, **base, **dict(swept)}
            where = entry.where() if entry is not None else "study.set"
            if swept:
                point_text = ", ".join(f"{k}={_format_value(v)}" for k, v in swept)
                where = f"setting {index} ({point_text})" if entry is None else f"{where} at {point_text}"
            config = _load(experiment, overrides, where)
            resolved = config.to_dict()
            values = tuple((key, settings_list.config_value(resolved, key)) for key in columns) + swept
            label = None
            if entry is not None:
                label = entry.label if entry.label is not None else settings_list.default_label(entry.overrides)
                clash = next((s for s, _o in out if s.listed == label and not swept), None)
                if clash is not None:
                    raise StudyError(f"{entry.where()}: its label {label!r} is already used by another setting")
            out.append((Setting(index, values, config, listed=label, sweep_values=swept), overrides))
    return out


def load_study(path: Path | str) -> Study:
    """Read and validate a study file; raises :class:`StudyError` with one line."""
    path = Path(path)
    data, text = read_toml(path, "study file", StudyError)
    try:
        return build_study(data, source=text, path=path)
    except StudyError as exc:
        raise StudyError(f"{path}: {exc}") from None


def is_study_file(path: Path | str) -> bool:
    """True if ``path`` is a TOML file with a [study] table (how `make` finds shipped studies)."""
    try:
        data, _ = read_toml(Path(path), "study file", StudyError)
    except StudyError:
        return False
    return "study" in data
