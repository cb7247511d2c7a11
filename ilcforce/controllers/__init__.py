"""The method registry: one :class:`MethodSpec` per ``--method`` name (Gymnasium ``EnvSpec`` style).

A spec says everything the rest of ilcforce needs about a method: its name (the ``--method`` value
and the TOML section of its gains), title, short label and colour for figures and tables, the module
holding its law, controller class and gains dataclass, its memory layout, and how it learns.
Figures, tables, the report, the CLI help, the config defaults and the Makefile (``python -m
ilcforce.controllers``) all read the registry; nothing else lists the methods. Adding a method is
one new module implementing :class:`~ilcforce.controllers.base.Controller` and one entry below (or,
outside ilcforce, a plugin: below).

The registry is cheap to import: a spec names its module by path and imports it only when its
controller or gains class is asked for, and a law's kernel is loaded only when first used
(:class:`~ilcforce.controllers.nd.compiled_law`).

**Plugins.** An installed package adds a method of its own, without a fork, through the entry-point
group :data:`ENTRY_POINT_GROUP` (``ilcforce.methods``, Gymnasium's convention): each entry point is
named after the method and points at its :class:`MethodSpec` (or at a function returning one);
docs/plugins.md and ``examples/ilcforce-plugin-example/`` show one. The registry loads them into
:data:`REGISTRY` after the shipped methods, on first use and once per process, so a plugin method is
the same to the rest of ilcforce as a shipped one. A plugin that cannot be loaded is left out with
one line on stderr naming it and the problem (``REGISTRY.problems()``); the shipped methods never
depend on it.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import os
import re
import sys
import threading
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

#: How a method learns (MethodSpec.learns).
LEARNS = {
    "none": "no learning: a fixed law",
    "within": "updates its memory at each control sample while the iteration runs",
    "between": "updates its memory after each iteration, from the finished iteration (end_iteration)",
}


@dataclass(frozen=True)
class MethodSpec:
    """Everything others need about one method.

    ``carries_memory`` says whether the memory learned in iteration j is what iteration j + 1
    starts from (iterative learning); a method that adapts within an iteration only restarts
    from the same memory every iteration.
    """

    name: str  # --method value and TOML section of the gains
    title: str  # one line for reports and help
    label: str  # short legend / column label
    color: str  # matplotlib colour ("C<n>": n-th colour of the report style's cycle)
    module: str  # module holding the law, the controller class and the gains dataclass
    controller: str  # controller class name in ``module``
    gains: str  # gains dataclass name in ``module``
    learns: str  # a key of LEARNS
    carries_memory: bool  # memory of iteration j seeds iteration j + 1
    in_paper: bool  # one of the paper's C1, C2, C3 (the report's claims need exactly these)
    reference: str  # where the law comes from

    def __post_init__(self) -> None:
        if self.learns not in LEARNS:
            raise ValueError(f"{self.name}: learns must be one of {', '.join(LEARNS)}, got {self.learns!r}")

    def _module(self):
        return importlib.import_module(self.module)

    @property
    def controller_class(self) -> type:
        return getattr(self._module(), self.controller)

    @property
    def gains_class(self) -> type:
        return getattr(self._module(), self.gains)

    @property
    def memory_layout(self) -> dict[str, tuple[int, int, str]]:
        """The controller class's memory blocks (name -> first column, last + 1, unit), as for the
        five-bar. An instance may be wider: C3 on a plant with gravity adds Theta's G block, so ask
        the controller made for the experiment (``experiment.make_controller``) for its own layout."""
        return dict(self.controller_class.memory_layout)


_ENTRIES = (
    MethodSpec("c1", "C1: sliding mode control with nominal model (eq. 26)", "C1 (SMC)", "C0",
               "ilcforce.controllers.c1", "C1Controller", "C1Gains", "none", False, True,
               "the paper, eq. (26)"),
    MethodSpec("c2", "C2: traditional ILC (eq. 27)", "C2 (ILC)", "C1",
               "ilcforce.controllers.c2", "C2Controller", "C2Gains", "within", True, True,
               "the paper, eq. (27); Azenha (2000)"),
    MethodSpec("c3", "C3: ILC based on sliding mode (eq. 14), the paper's method", "C3 (ILC + SMC)", "C2",
               "ilcforce.controllers.c3", "C3Controller", "C3Gains", "within", True, True,
               "the paper, eq. (14)"),
    MethodSpec("smc-bl", "SMC-BL: C1 with a boundary layer, sat(sigma / phi) for sgn", "SMC-BL", "C3",
               "ilcforce.controllers.smc_bl", "SMCBoundaryLayerController", "SMCBoundaryLayerGains",
               "none", False, False, "Slotine & Li, Applied Nonlinear Control (1991), sec. 7.2"),
    MethodSpec("pd-ilc", "PD-ILC: PD feedback + PD-type ILC with a zero-phase Q filter", "PD-ILC", "C4",
               "ilcforce.controllers.pd_ilc", "PDILCController", "PDILCGains", "between", True, False,
               "Arimoto, Kawamura & Miyazaki (1984); Bristow, Tharayil & Alleyne (2006)"),
    MethodSpec("c3-leak", "C3-leak: C3 with leakage on Theta_hat, alpha_hat and a bound on alpha_hat",
               "C3-leak", "C5", "ilcforce.controllers.c3_leak", "C3LeakController", "C3LeakGains",
               "within", True, False, "the paper's eq. (14) with sigma-modification (Ioannou & Sun 1996)"),
    MethodSpec("sl-adapt", "SL-adapt: Slotine-Li adaptive control of the robot's constant physical parameters",
               "SL-adapt", "C7", "ilcforce.controllers.sl_adapt", "SlotineLiController", "SlotineLiGains",
               "within", True, False, "Slotine & Li (1987; 1991 sec. 9.2, eqs. 9.25-9.27)"),
    MethodSpec("c2-robust", "C2-robust: C2 learning after the start transient, its memory Q-filtered",
               "C2-robust", "#8B3A00", "ilcforce.controllers.c2_robust", "C2RobustController", "C2RobustGains",
               "within", True, False, "the paper's eq. (27) with a learning window and a zero-phase Q filter "
               "(Bristow, Tharayil & Alleyne 2006)"),
    MethodSpec("c3-robust", "C3-robust: C3 learning after the start transient, its memory Q-filtered, "
               "alpha_hat bounded", "C3-robust", "#00573F", "ilcforce.controllers.c3_robust",
               "C3RobustController", "C3RobustGains", "within", True, False,
               "the paper's eq. (14) with a learning window, a zero-phase Q filter and projection of alpha_hat"),
    MethodSpec("no-ilc", "NO-ILC: PD feedback + norm-optimal ILC on the nominal closed loop's lifted model, "
               "Q-filtered", "NO-ILC", "C6", "ilcforce.controllers.no_ilc", "NOILCController", "NOILCGains",
               "between", True, False, "Amann, Owens & Rogers (1996); the Q filter of Bristow, Tharayil & "
               "Alleyne (2006)"),
)

#: the entry-point group through which an installed package declares a method (docs/plugins.md)
ENTRY_POINT_GROUP = "ilcforce.methods"
#: a method name: the --method value, a TOML section, part of file names (results/<experiment>/<name>.h5)
_METHOD_NAME = re.compile(r"[a-z][a-z0-9_-]{0,39}")


#: names a method may not take: its gains would be a TOML section of the same name as an experiment file's own
#: (ilcforce.config.Config's fields; tests/test_plugins.py pins the two lists) or a study's or a tuning's table
RESERVED = ("experiment", "plant", "wall", "reference", "simulation", "noise", "surface", "tuning", "gains", "study",
            "tune")

#: set in the environment once a process has said which plugins did not load, so that the processes it starts
#: (a study's Dask workers, a report's pool) do not say it again
_SAID = "ILCFORCE_PLUGIN_PROBLEMS_SAID"


class PluginError(ValueError):
    """Why an entry point of :data:`ENTRY_POINT_GROUP` gives no usable method (one line)."""


def _plugin_spec(entry_point, taken: Mapping[str, MethodSpec]) -> MethodSpec:
    """The spec an entry point declares, checked as far as the rest of ilcforce relies on it without
    running the law (PluginError otherwise): the module, the controller and gains classes load, the
    gains have defaults (every experiment carries every method's gains), and the controller has a law."""
    try:
        found = entry_point.load()
        spec = found() if callable(found) and not isinstance(found, MethodSpec) else found
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plugin's fault is reported, not raised
        raise PluginError(f"cannot be loaded ({type(exc).__name__}: {_first_line(exc)})") from None
    if not isinstance(spec, MethodSpec):
        raise PluginError(f"gives a {type(spec).__name__}, not an ilcforce.controllers.MethodSpec")
    if spec.name != entry_point.name:
        raise PluginError(f"the entry point is named {entry_point.name!r} but its spec {spec.name!r}")
    if not _METHOD_NAME.fullmatch(spec.name):
        raise PluginError(f"{spec.name!r} is not a method name (lower-case letters, digits, '-', '_'; a letter "
                          "first; at most 40 characters)")
    if spec.name in taken:
        raise PluginError(f"{spec.name!r} is already a method ({taken[spec.name].module})")
    if spec.name in RESERVED:
        raise PluginError(f"{spec.name!r} is a section of ilcforce's own files; a method's gains cannot take it")
    if spec.in_paper:
        raise PluginError("in_paper must be False (the paper's methods are the shipped c1, c2 and c3)")
    try:
        controller, gains = spec.controller_class, spec.gains_class
    except (Exception, SystemExit) as exc:  # noqa: BLE001
        raise PluginError(f"module {spec.module}: {type(exc).__name__}: {_first_line(exc)}") from None
    if not (isinstance(gains, type) and dataclasses.is_dataclass(gains)):
        raise PluginError(f"{spec.module}.{spec.gains} is not a dataclass")
    try:
        gains()
    except Exception as exc:  # noqa: BLE001
        raise PluginError(f"{spec.gains}() with its defaults fails: {_first_line(exc)}") from None
    if not isinstance(controller, type):
        raise PluginError(f"{spec.module}.{spec.controller} is not a class")
    if inspect.getattr_static(controller, "law", None) is None:
        raise PluginError(f"{spec.controller} has no law (law = compiled_law(...), docs/plugins.md)")
    if getattr(controller, "name", None) != spec.name:
        raise PluginError(f"{spec.controller}.name is {getattr(controller, 'name', None)!r}, not {spec.name!r}")
    layout = getattr(controller, "memory_layout", None)
    if not (isinstance(layout, dict) and all(isinstance(v, tuple) and len(v) == 3 for v in layout.values())):
        raise PluginError(f"{spec.controller}.memory_layout must be a dict of name -> (first column, last + 1, unit)")
    return spec


def _first_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:200] if text else type(exc).__name__


@dataclass(frozen=True)
class EntryPoint:
    """One ``name = module:attribute`` line of an installed distribution's entry points in
    :data:`ENTRY_POINT_GROUP` (what ``importlib.metadata.EntryPoint`` holds for it)."""

    name: str
    value: str
    package: str = ""  # the distribution that declares it ("" if unknown)

    def load(self):
        """Import the module and return the attribute (``importlib.metadata``'s rule; extras ignored)."""
        module, _, attribute = self.value.split("[")[0].partition(":")
        found = importlib.import_module(module.strip())
        for part in filter(None, attribute.strip().split(".")):
            found = getattr(found, part)
        return found


def _group_lines(text: str, group: str):
    """The ``name = value`` lines of ``[group]`` in an entry_points.txt (an INI file)."""
    inside = False
    for line in text.splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            inside = line[1:-1].strip() == group
        elif inside and "=" in line and not line.startswith(("#", ";")):
            name, _, value = line.partition("=")
            yield name.strip(), value.strip()


def _entry_points() -> list[EntryPoint]:
    """The entry points of :data:`ENTRY_POINT_GROUP` of the distributions on ``sys.path`` (the first of a
    name wins, as for ``importlib.metadata``), sorted by name.

    Read here rather than through ``importlib.metadata``, whose import and scan (email, csv, zipfile, ...)
    is about 30 ms of every cold command, ``ilcforce --help`` included; this reads only each
    distribution's entry_points.txt (1-3 ms)."""
    seen, found = set(), []
    for entry in sys.path:
        try:
            names = sorted(os.listdir(entry or "."))
        except OSError:  # not a folder (a zip file, a missing path)
            continue
        for item in names:
            stem, dot, kind = item.rpartition(".")
            if not dot or kind not in ("dist-info", "egg-info"):
                continue
            package = stem.split("-")[0]
            key = re.sub(r"[-_.]+", "_", package).lower()
            if key in seen:
                continue
            seen.add(key)
            try:
                with open(os.path.join(entry or ".", item, "entry_points.txt"), encoding="utf-8") as handle:
                    text = handle.read()
            except (OSError, UnicodeDecodeError):
                continue
            found += [EntryPoint(name, value, package) for name, value in _group_lines(text, ENTRY_POINT_GROUP)]
    return sorted(found, key=lambda ep: (ep.name, ep.value))


class Registry(Mapping):
    """method name -> :class:`MethodSpec`, in report order: the shipped methods (the paper's three first),
    then the installed plugins' by name. The plugins are loaded at the first look into the registry, once
    per process (not at import: the entry points are read only by a process that needs a method)."""

    def __init__(self, shipped: tuple[MethodSpec, ...]) -> None:
        self._shipped = {spec.name: spec for spec in shipped}
        self._all: dict[str, MethodSpec] | None = None
        self._problems: list[str] = []
        self._lock = threading.RLock()
        self._loading = False

    def _specs(self) -> dict[str, MethodSpec]:
        if self._all is not None:
            return self._all
        with self._lock:
            if self._all is not None:
                return self._all
            if self._loading:  # a plugin's module looks into the registry while it loads: the shipped ones
                return self._shipped
            self._loading = True
            try:
                self._all = self._load()
            finally:
                self._loading = False
        if self._problems and not os.environ.get(_SAID):  # once per command: its worker processes inherit _SAID
            os.environ[_SAID] = "1"
            for line in self._problems:
                print(line, file=sys.stderr)
        return self._all

    def _load(self) -> dict[str, MethodSpec]:
        specs = dict(self._shipped)
        try:
            found = _entry_points()
        except Exception as exc:  # noqa: BLE001 - damaged package metadata: the shipped methods still run
            self._problems.append(f"ilcforce: plugin methods not loaded: the installed packages' entry points "
                                  f"cannot be read ({_first_line(exc)})")
            return specs
        for entry_point in found:
            try:
                spec = _plugin_spec(entry_point, specs)
            except PluginError as exc:
                package = entry_point.package
                source = f"{entry_point.value}" + (f" of package {package}" if package else "")
                self._problems.append(f"ilcforce: plugin method {entry_point.name!r} ({source}) left out: {exc}")
                continue
            specs[spec.name] = spec
        return specs

    def __getitem__(self, name: str) -> MethodSpec:
        return self._specs()[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._specs())

    def __len__(self) -> int:
        return len(self._specs())

    def __contains__(self, name: object) -> bool:
        return name in self._specs()

    def __repr__(self) -> str:
        return f"Registry({', '.join(self)})"

    @property
    def shipped(self) -> tuple[str, ...]:
        """The methods that come with ilcforce (no plugin), in report order; reading it loads no plugin."""
        return tuple(self._shipped)

    def shipped_specs(self) -> tuple[MethodSpec, ...]:
        """The shipped methods' specs, in report order, without loading any plugin (the ahead-of-time
        build compiles these laws alone)."""
        return tuple(self._shipped.values())

    def plugins(self) -> tuple[str, ...]:
        """The installed plugins' methods that loaded."""
        return tuple(name for name in self if name not in self._shipped)

    def problems(self) -> tuple[str, ...]:
        """One line per plugin that did not load (each also printed on stderr, once per command)."""
        self._specs()
        return tuple(self._problems)


#: method name -> spec, in report order (the paper's three first, then the other shipped ones, then plugins).
REGISTRY: Registry = Registry(_ENTRIES)

#: the paper's methods, in the paper's order
PAPER_METHODS: tuple[str, ...] = tuple(spec.name for spec in _ENTRIES if spec.in_paper)


def method_names() -> tuple[str, ...]:
    """Every registered method, in report order."""
    return tuple(REGISTRY)


class MethodNameError(ValueError):
    """A name that is no registered method; the message is one line with the choices."""


def canonical_method(name: str) -> str:
    """The registry's name for ``name``: method names are matched without regard to case or
    surrounding spaces (``"C3"``, ``" c3 "`` -> ``"c3"``; ``"SMC-BL"`` -> ``"smc-bl"``), and every
    store, table and folder then uses the registry's spelling. MethodNameError (one line, with a
    close match if there is one) for anything else."""
    text = name.strip().lower() if isinstance(name, str) else name
    if text in REGISTRY:
        return text
    import difflib

    close = difflib.get_close_matches(str(text), list(REGISTRY), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else ""
    raise MethodNameError(f"unknown method {name!r}{hint}; choose from {', '.join(REGISTRY)}")


def __getattr__(name: str):
    # ``from ilcforce.controllers import Controller`` without importing numba at registry import
    if name == "Controller":
        from ilcforce.controllers.base import Controller
        return Controller
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["ENTRY_POINT_GROUP", "LEARNS", "MethodNameError", "MethodSpec", "PAPER_METHODS", "PluginError", "REGISTRY",
           "Registry", "Controller", "canonical_method", "method_names"]
