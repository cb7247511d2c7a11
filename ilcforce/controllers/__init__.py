"""The method registry: one :class:`MethodSpec` per ``--method`` name (Gymnasium ``EnvSpec`` style).

A spec says everything the rest of ilcforce needs about a method: its name (the ``--method`` value
and the TOML section of its gains), title, short label and colour for figures and tables, the module
holding its law, controller class and gains dataclass, its memory layout, and how it learns.
Figures, tables, the report, the CLI help, the config defaults and the Makefile (``python -m
ilcforce.controllers``) all read the registry; nothing else lists the methods. Adding a method is
one new module implementing :class:`~ilcforce.controllers.base.Controller` and one entry below.

The registry is cheap to import: a spec names its module by path and imports it only when its
controller or gains class is asked for, and a law's kernel is loaded only when first used
(:class:`~ilcforce.controllers.base.compiled_law`).
"""

from __future__ import annotations

import importlib
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
)

#: method name -> spec, in report order (the paper's three first).
REGISTRY: dict[str, MethodSpec] = {spec.name: spec for spec in _ENTRIES}

#: the paper's methods, in the paper's order
PAPER_METHODS: tuple[str, ...] = tuple(name for name, spec in REGISTRY.items() if spec.in_paper)


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


__all__ = ["LEARNS", "MethodNameError", "MethodSpec", "PAPER_METHODS", "REGISTRY", "Controller", "canonical_method",
           "method_names"]
