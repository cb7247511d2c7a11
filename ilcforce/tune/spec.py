"""The tuning file: which gains of which methods to tune, on what, scored how, checked how; validated in
full before any trial runs (docs/tuning.md has the whole format and the reasons).

File format (TOML)::

    [tune]
    name = "serial2r-tune"               # results/tuning/<name>/; a plain file name
    experiment = "serial2r.toml"         # relative to the tuning file (then to the working directory)
    methods = ["c1", "c2", "c3"]         # each gets its own sampler and a budget by its dimension
    seeds = "0-2"                        # scoring seeds: every trial runs `iterations` on each
    iterations = 20                      # the scored horizon; its last `score_last` iterations are scored
    score_last = 5                       # optional (default 5)
    objective = "both"                   # the error objective: "both" (default), "position" or "force"
    chattering = "settled-H"             # the chattering objective (the one kind there is; see below)
    check_seeds = "10-11"                # stability check: other seeds, a horizon >= 3 x iterations
    check_iterations = 60
    heldout_seeds = "90-93"              # the front re-evaluated on seeds never searched or checked
    heldout_iterations = 60              # >= 3 x iterations
    sampler_seed = 0
    [tune.budget]                        # trials = base + per_dimension x (searched parameters), then
    base = 10                            #   more, one at a time, until the front stops improving
    per_dimension = 5                    #   (hypervolume gain under stop_gain over the last quarter of
    extend = 3                           #   trials), at most extend x the first budget
    stop_gain = 0.01
    [tune.cap]                           # the chattering cap the shipped gains must keep
    reference = "c1"                     # a method of tune.methods, with the experiment's gains
    factor = 1.0                         # cap = factor x its settled H per task axis
    [tune.set]                           # fixed overrides, exactly as --set
    [tune.gains.c3]                      # the searched gains of one method
    k = { low = 1.0, high = 1e4, log = true }     # a vector gain: every element searched on this range
    gamma = [{ low = 400, high = 4e4, log = true }, 40.0, ...]   # per element: a range or a fixed number

The objectives (both minimised) of a trial, per scoring seed, over the scored iterations
``iterations - score_last .. iterations - 1``: the **error** ``log10(e_P / 1 mm) + log10(e_F / 1 N)``
of the mean RMS norms ("both"; "position" or "force" keep one term), and the **chattering**
``log10(max over the task's axes a of H_a / cap_a)`` of the mean settled H per task axis (x, y on the
planar task, u, v, n on a 3-axis one: :attr:`Tuning.axes`), where the cap is the reference method's settled
H with the experiment's gains on the same seeds, one value per axis (so 0 is "as much as the reference");
then the median over seeds. A trial is **feasible** when every check seed runs the whole
``check_iterations`` without divergence and the growth test (:mod:`ilcforce.stability`) flags none.
Every problem raises :class:`TuneError` with one line naming the key.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import typing
from dataclasses import dataclass
from pathlib import Path

from ilcforce.config import Config, ConfigError
from ilcforce.config_load import load_config, shown
from ilcforce.records import task_axes
from ilcforce.store.schema import STUDY_NAME
from ilcforce.study.spec import StudyError, parse_seeds
from ilcforce.tomlfile import read_toml
from ilcforce.tune.objectives import CHATTERING, OBJECTIVES


class TuneError(ValueError):
    """An invalid tuning file or tuning request; the message is one line."""


TUNE_KEYS = ("name", "description", "experiment", "methods", "seeds", "iterations", "score_last", "objective",
             "chattering", "check_seeds", "check_iterations", "heldout_seeds", "heldout_iterations", "sampler_seed",
             "budget", "cap", "set", "gains")
BUDGET_KEYS = ("base", "per_dimension", "extend", "stop_gain")
CAP_KEYS = ("reference", "factor")
#: The check and held-out horizons are at least this many times the scored one (a learning result holds
#: on the horizon a user runs: the shipped tuned gains diverged just past a 30-iteration tuning horizon).
HORIZON_FACTOR = 3
#: Trials per method allowed in one tuning file (a guard against typos).
MAX_TRIALS = 10_000


@dataclass(frozen=True)
class Budget:
    """A method's trials: ``base + per_dimension x d`` first (d its searched parameters), then one more at
    a time until the front's hypervolume gained less than ``stop_gain`` (relative) over the last quarter
    of its trials, at most ``extend`` times the first budget."""

    base: int = 10
    per_dimension: int = 5
    extend: int = 3
    stop_gain: float = 0.01

    def first(self, dimension: int) -> int:
        return self.base + self.per_dimension * dimension

    def most(self, dimension: int) -> int:
        return self.extend * self.first(dimension)
RANGE_KEYS = ("low", "high", "log")


@dataclass(frozen=True)
class GainRange:
    """The searched range of one scalar (one element of a vector gain)."""

    low: float
    high: float
    log: bool = False

    def contains(self, value: float) -> bool:
        return self.low <= value <= self.high


@dataclass(frozen=True)
class SearchedGain:
    """One field of a method's gains: per element a :class:`GainRange` or a fixed number.

    ``vector`` is False for a scalar field (one element)."""

    field: str
    elements: tuple[GainRange | float, ...]
    vector: bool
    integer: bool = False

    def parameter_names(self) -> list[tuple[str, GainRange]]:
        """(Optuna parameter name, range) of every searched element: ``k[0]``, ``eta``."""
        return [(f"{self.field}[{i}]" if self.vector else self.field, r)
                for i, r in enumerate(self.elements) if isinstance(r, GainRange)]

    def value(self, params: dict):
        """The field's value from the sampled ``params`` (fixed elements as given)."""
        values = []
        for i, r in enumerate(self.elements):
            if isinstance(r, GainRange):
                v = params[f"{self.field}[{i}]" if self.vector else self.field]
            else:
                v = r
            values.append(int(round(v)) if self.integer else float(v))
        return values if self.vector else values[0]


@dataclass(frozen=True)
class Tuning:
    """A parsed and validated tuning file."""

    name: str
    description: str
    source: str  # the tuning file's text (provenance)
    path: Path | None
    experiment: Path
    methods: tuple[str, ...]
    seeds: tuple[int, ...]
    iterations: int
    score_last: int
    objective: str
    chattering: str
    check_seeds: tuple[int, ...]
    check_iterations: int
    heldout_seeds: tuple[int, ...]
    heldout_iterations: int
    budget: Budget
    cap_reference: str
    cap_factor: float
    sampler_seed: int
    fixed: dict  # [tune.set]
    gains: dict  # method -> tuple of SearchedGain
    base: Config  # the experiment with [tune.set] and the horizon applied (seed 0)

    def parameters(self, method: str) -> list[tuple[str, GainRange]]:
        """Every searched parameter of ``method``, in file order."""
        return [p for g in self.gains[method] for p in g.parameter_names()]

    def first_budget(self, method: str) -> int:
        """The trials ``method`` runs before its convergence is judged (grows with its dimension)."""
        return self.budget.first(len(self.parameters(method)))

    def most_trials(self, method: str) -> int:
        """The most trials ``method`` may run (its search stops earlier once its front stops improving)."""
        return self.budget.most(len(self.parameters(method)))

    @property
    def axes(self) -> tuple[str, ...]:
        """The experiment's task axes (:func:`ilcforce.records.task_axes`): the chattering objective, the cap
        and each seed's stored H are per axis."""
        return task_axes(self.base.dimension)

    @property
    def score_iterations(self) -> int:
        """The scored runs' length (the check and held-out runs are longer)."""
        return self.iterations

    def overrides(self, method: str, params: dict) -> dict:
        """Dotted --set overrides of the sampled ``params`` (an empty ``params``: none, the defaults)."""
        if not params:
            return {}
        return {f"{method}.{g.field}": g.value(params) for g in self.gains[method]}

    def default_params(self, method: str) -> dict:
        """The experiment's own gains as sampled parameters (trial 0)."""
        gains = self.base.gains[method]
        out = {}
        for g in self.gains[method]:
            value = getattr(gains, g.field)
            for i, r in enumerate(g.elements):
                if isinstance(r, GainRange):
                    out[f"{g.field}[{i}]" if g.vector else g.field] = float(value[i] if g.vector else value)
        return out

    def defaults_in_space(self, method: str) -> bool:
        """Whether the experiment's own gains are a point of the search space (every searched element
        in its range, every fixed element equal to the experiment's): only then does the sampler
        learn from trial 0; it is scored and can be chosen either way."""
        params = self.default_params(method)
        if not all(r.contains(params[n]) for n, r in self.parameters(method)):
            return False
        gains = self.base.gains[method]
        return all(g.value(params) == (list(getattr(gains, g.field)) if g.vector else getattr(gains, g.field))
                   for g in self.gains[method])

    def trial_config(self, method: str, params: dict, seed: int, iterations: int | None = None) -> Config:
        """The configuration one cell of a trial runs (``iterations``: default the scored horizon);
        ConfigError if the gains are not valid."""
        overrides = {**self.fixed, **self.overrides(method, params), "experiment.seed": seed,
                     "experiment.iterations": iterations or self.iterations}
        return load_config(self.experiment, overrides)

    def definition(self) -> dict:
        """What identifies the tuning (stored; a rerun must match it)."""
        return {"name": self.name, "experiment": self.base.to_json(), "methods": list(self.methods),
                "seeds": list(self.seeds), "iterations": self.iterations, "score_last": self.score_last,
                "objective": self.objective, "chattering": self.chattering, "check_seeds": list(self.check_seeds),
                "check_iterations": self.check_iterations, "heldout_seeds": list(self.heldout_seeds),
                "heldout_iterations": self.heldout_iterations, "budget": dataclasses.asdict(self.budget),
                "cap": {"reference": self.cap_reference, "factor": self.cap_factor},
                "sampler_seed": self.sampler_seed,
                "gains": {m: [dataclasses.asdict(g) for g in gs] for m, gs in self.gains.items()}}


def definition_axes(definition: dict) -> tuple[str, ...]:
    """The task axes of a stored search (:meth:`Tuning.definition`): its experiment's, from the selection's
    width; ValueError when the experiment has no task of 2 or 3 axes."""
    return task_axes(len(json.loads(definition["experiment"])["surface"]["selection"]))


def _positive_int(table: dict, key: str, default=None, *, at_most: int | None = None, where: str = "tune") -> int:
    value = table.get(key, default)
    if value is None:
        raise TuneError(f"{where}.{key} is missing")
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise TuneError(f"{where}.{key} must be an integer >= 1, got {shown(value)}")
    if at_most is not None and value > at_most:
        raise TuneError(f"{where}.{key} must be at most {at_most}, got {value}")
    return value


def _seeds(table: dict, key: str) -> tuple[int, ...]:
    try:
        return parse_seeds(table[key])
    except StudyError as exc:
        raise TuneError(str(exc).replace("study.seeds", f"tune.{key}")) from None


def _budget(spec) -> Budget:
    if not isinstance(spec, dict):
        raise TuneError(f"[tune.budget] must be a table {{ {', '.join(BUDGET_KEYS)} }}, got {shown(spec)}")
    for key in spec:
        if key not in BUDGET_KEYS:
            raise TuneError(f"unknown key tune.budget.{key}{_hint(key, BUDGET_KEYS)}")
    default = Budget()
    base = _positive_int(spec, "base", default.base, at_most=MAX_TRIALS, where="tune.budget")
    per_dimension = spec.get("per_dimension", default.per_dimension)
    if isinstance(per_dimension, bool) or not isinstance(per_dimension, int) or not 0 <= per_dimension <= 1000:
        raise TuneError(f"tune.budget.per_dimension must be an integer in 0 .. 1000, got {shown(per_dimension)}")
    extend = _positive_int(spec, "extend", default.extend, at_most=100, where="tune.budget")
    stop_gain = _number("tune.budget.stop_gain", spec.get("stop_gain", default.stop_gain))
    if not 0 < stop_gain < 1:
        raise TuneError(f"tune.budget.stop_gain must be between 0 and 1 (a relative gain), got {stop_gain:g}")
    return Budget(base, per_dimension, extend, stop_gain)


def _cap(spec, methods: list) -> tuple[str, float]:
    if not isinstance(spec, dict):
        raise TuneError(f"[tune.cap] must be a table {{ reference, factor }}, got {shown(spec)}")
    for key in spec:
        if key not in CAP_KEYS:
            raise TuneError(f"unknown key tune.cap.{key}{_hint(key, CAP_KEYS)}")
    if "reference" not in spec:
        raise TuneError("tune.cap has no reference: name the method whose chattering with the experiment's gains "
                        "is the cap (e.g. reference = \"c1\")")
    reference = spec["reference"]
    if reference not in methods:
        raise TuneError(f"tune.cap.reference {shown(reference)} is not in tune.methods (its trial 0 measures the cap)")
    factor = _number("tune.cap.factor", spec.get("factor", 1.0))
    if not factor > 0:
        raise TuneError(f"tune.cap.factor must be above 0, got {factor:g}")
    return reference, factor


def _number(where: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise TuneError(f"{where} must be a finite number, got {shown(value)}")
    return float(value)


def _range(where: str, spec) -> GainRange | float:
    """A range table ``{low, high, log}``, or a number (held fixed)."""
    if not isinstance(spec, dict):
        return _number(where, spec)
    for key in spec:
        if key not in RANGE_KEYS:
            raise TuneError(f"unknown key {where}.{key}{_hint(key, RANGE_KEYS)}; a range is {{ low, high, log }}")
    if "low" not in spec or "high" not in spec:
        raise TuneError(f"{where} needs low and high")
    low, high = _number(f"{where}.low", spec["low"]), _number(f"{where}.high", spec["high"])
    log = spec.get("log", False)
    if not isinstance(log, bool):
        raise TuneError(f"{where}.log must be true or false, got {shown(log)}")
    if not low < high:
        raise TuneError(f"{where}: low must be below high, got {low:g} and {high:g}")
    if log and low <= 0:
        raise TuneError(f"{where}: a log range needs low > 0, got {low:g}")
    return GainRange(low, high, log)


def _hint(key: str, options) -> str:
    close = difflib.get_close_matches(str(key), list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _searched_gains(method: str, table, base: Config) -> tuple[SearchedGain, ...]:
    where = f"tune.gains.{method}"
    if not isinstance(table, dict) or not table:
        raise TuneError(f"[{where}] must be a table naming at least one gain, got {shown(table)}")
    gains = base.gains[method]
    fields = {f.name: f for f in dataclasses.fields(gains)}
    hints = typing.get_type_hints(type(gains))
    out = []
    for name, spec in table.items():
        if name not in fields:
            raise TuneError(f"unknown gain {where}.{name}{_hint(name, fields)}; {method}'s gains are "
                            f"{', '.join(fields)}")
        current = getattr(gains, name)
        if isinstance(current, str) or hints[name] is str:
            raise TuneError(f"{where}.{name} is a choice, not a number: set it in [tune.set]")
        integer = hints[name] is int
        if isinstance(current, tuple):
            if isinstance(spec, list):
                if len(spec) != len(current):
                    per = (f"task axis {', '.join(task_axes(base.dimension))} of {base.experiment.name}"
                           if len(current) == base.dimension else "element")
                    raise TuneError(f"{where}.{name} must list {len(current)} entries (one per {per}), "
                                    f"got {len(spec)}")
                elements = tuple(_range(f"{where}.{name}[{i}]", s) for i, s in enumerate(spec))
            elif isinstance(spec, dict):
                elements = (_range(f"{where}.{name}", spec),) * len(current)
            else:
                raise TuneError(f"{where}.{name} must be a range {{ low, high, log }} or a list of one per "
                                f"element, got {shown(spec)}")
            vector = True
        else:
            if not isinstance(spec, dict):
                raise TuneError(f"{where}.{name} must be a range {{ low, high, log }}, got {shown(spec)}")
            elements, vector = (_range(f"{where}.{name}", spec),), False
        if not any(isinstance(e, GainRange) for e in elements):
            raise TuneError(f"{where}.{name} holds every element fixed: set it in [tune.set] instead")
        if integer:  # Optuna's integer ranges: whole bounds, and a log range from 1 (it refuses less)
            for e in elements:
                bounds = (e.low, e.high) if isinstance(e, GainRange) else (e,)
                if not all(float(b).is_integer() for b in bounds) or isinstance(e, GainRange) and e.log and e.low < 1:
                    raise TuneError(f"{where}.{name} is an integer gain: its range needs whole numbers"
                                    f"{' and low >= 1 (a log range)' if isinstance(e, GainRange) and e.log else ''},"
                                    f" got {e if not isinstance(e, GainRange) else f'{e.low:g} .. {e.high:g}'}")
        out.append(SearchedGain(name, elements, vector, integer))
    return tuple(out)


def _resolve_experiment(value, path: Path | None) -> Path:
    if not isinstance(value, str) or not value:
        raise TuneError(f"tune.experiment must be a path to an experiment TOML file, got {shown(value)}")
    candidates = ([path.parent / value] if path is not None and not Path(value).is_absolute() else []) + [Path(value)]
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    raise TuneError(f"tune.experiment: no experiment file {' or '.join(str(c) for c in dict.fromkeys(candidates))}")


def build_tuning(data: dict, *, source: str = "", path: Path | None = None) -> Tuning:
    """Validate a parsed tuning file (the whole TOML document)."""
    from ilcforce.controllers import REGISTRY

    if not isinstance(data, dict) or "tune" not in data:
        raise TuneError("a tuning file needs a [tune] table")
    extra = [k for k in data if k != "tune"]
    if extra:
        raise TuneError(f"unknown top-level table [{extra[0]}] in a tuning file; only [tune] is read")
    table = data["tune"]
    if not isinstance(table, dict):
        raise TuneError("[tune] must be a table")
    for key in table:
        if key not in TUNE_KEYS:
            raise TuneError(f"unknown key tune.{key}{_hint(key, TUNE_KEYS)}")
    for key in ("name", "experiment", "methods", "seeds", "iterations", "check_seeds", "check_iterations",
                "heldout_seeds", "heldout_iterations", "cap", "gains"):
        if key not in table:
            raise TuneError(f"tune.{key} is missing")
    name = table["name"]
    if not isinstance(name, str) or not STUDY_NAME.fullmatch(name) or name in (".", ".."):
        raise TuneError(f"tune.name must be a plain file name (letters, digits, '.', '_', '-'), got {shown(name)}")
    description = table.get("description", "")
    if not isinstance(description, str):
        raise TuneError(f"tune.description must be a string, got {shown(description)}")
    methods = table["methods"]
    if not isinstance(methods, list) or not methods:
        raise TuneError(f"tune.methods must be a non-empty list of method names, got {shown(methods)}")
    for method in methods:
        if method not in REGISTRY:
            raise TuneError(f"tune.methods: unknown method {method!r}{_hint(method, REGISTRY)}; choose from "
                            f"{', '.join(REGISTRY)}")
    if len(set(methods)) != len(methods):
        raise TuneError("tune.methods lists a method twice")
    seeds = _seeds(table, "seeds")
    iterations = _positive_int(table, "iterations", at_most=10_000)
    score_last = _positive_int(table, "score_last", min(5, iterations))
    if score_last > iterations:
        raise TuneError(f"tune.score_last ({score_last}) must not exceed tune.iterations ({iterations})")
    objective = table.get("objective", "both")
    if objective not in OBJECTIVES:
        raise TuneError(f"tune.objective: unknown objective {shown(objective)}; choose from {', '.join(OBJECTIVES)}")
    chattering = table.get("chattering", CHATTERING[0])
    if chattering not in CHATTERING:
        raise TuneError(f"tune.chattering: unknown chattering objective {shown(chattering)}; choose from "
                        f"{', '.join(CHATTERING)}")
    check_seeds, heldout_seeds = _seeds(table, "check_seeds"), _seeds(table, "heldout_seeds")
    for name_a, a, name_b, b in (("seeds", seeds, "check_seeds", check_seeds), ("seeds", seeds, "heldout_seeds",
                                 heldout_seeds), ("check_seeds", check_seeds, "heldout_seeds", heldout_seeds)):
        shared = sorted(set(a) & set(b))
        if shared:
            raise TuneError(f"tune.{name_b} shares seed {shared[0]} with tune.{name_a}; the three sets of seeds "
                            "must be disjoint (a check or a held-out result on a searched seed proves nothing)")
    check_iterations = _positive_int(table, "check_iterations", at_most=10_000)
    heldout_iterations = _positive_int(table, "heldout_iterations", at_most=10_000)
    for key, value in (("check_iterations", check_iterations), ("heldout_iterations", heldout_iterations)):
        if value < HORIZON_FACTOR * iterations:
            raise TuneError(f"tune.{key} must be at least {HORIZON_FACTOR} x tune.iterations = "
                            f"{HORIZON_FACTOR * iterations}, got {value}")
    budget = _budget(table.get("budget", {}))
    reference, cap_factor = _cap(table["cap"], methods)
    sampler_seed = table.get("sampler_seed", 0)
    if isinstance(sampler_seed, bool) or not isinstance(sampler_seed, int) or not 0 <= sampler_seed < 2**31:
        raise TuneError(f"tune.sampler_seed must be an integer in [0, 2^31), got {shown(sampler_seed)}")
    fixed = table.get("set", {})
    if not isinstance(fixed, dict):
        raise TuneError(f"tune.set must be a table of \"section.key\" = value, got {shown(fixed)}")
    for key, value in fixed.items():
        if isinstance(value, dict):
            raise TuneError(f"tune.set: write keys as quoted dotted names, e.g. \"{key}.x\" = ..., not a table")
        if key in ("experiment.seed", "experiment.iterations"):
            raise TuneError(f"tune.set: {key} is set by tune.{'seeds' if key.endswith('seed') else 'iterations'}")
    experiment = _resolve_experiment(table["experiment"], path)
    try:
        base = load_config(experiment, {**fixed, "experiment.seed": 0, "experiment.iterations": iterations})
    except ConfigError as exc:
        raise TuneError(f"tune.set or tune.experiment: {exc}") from None
    gains_table = table["gains"]
    if not isinstance(gains_table, dict) or not gains_table:
        raise TuneError("[tune.gains] must hold one table per method, e.g. [tune.gains.c3]")
    for method in gains_table:
        if method not in methods:
            raise TuneError(f"[tune.gains.{method}]: {method!r} is not in tune.methods")
    gains = {}
    for method in methods:
        if method not in gains_table:
            raise TuneError(f"tune.methods lists {method!r} but [tune.gains.{method}] is missing")
        gains[method] = _searched_gains(method, gains_table[method], base)
        for g in gains[method]:
            if f"{method}.{g.field}" in fixed:
                raise TuneError(f"{method}.{g.field} is both searched and fixed in [tune.set]")
    return Tuning(name=name, description=description, source=source, path=path, experiment=experiment,
                  methods=tuple(methods), seeds=seeds, iterations=iterations, score_last=score_last,
                  objective=objective, chattering=chattering, check_seeds=check_seeds, check_iterations=check_iterations,
                  heldout_seeds=heldout_seeds, heldout_iterations=heldout_iterations, budget=budget,
                  cap_reference=reference, cap_factor=cap_factor, sampler_seed=sampler_seed,
                  fixed=dict(fixed), gains=gains, base=base)


def load_tuning(path: Path | str) -> Tuning:
    """Read and validate a tuning file; raises :class:`TuneError` with one line."""
    path = Path(path)
    data, text = read_toml(path, "tuning file", TuneError)
    try:
        return build_tuning(data, source=text, path=path)
    except TuneError as exc:
        raise TuneError(f"{path}: {exc}") from None
