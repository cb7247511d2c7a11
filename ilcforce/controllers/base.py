"""The one contract every controller implements, and the parts all of them share.

A controller has two halves:

* a compiled **law**, called by the simulation loop at every control sample. Its signature is fixed
  (:data:`LAW_SIGNATURE`) so that the loop is compiled and cached once and calls any law through a
  function pointer::

      law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag) -> (tau1, tau2)

  ``k`` is the control sample, ``t`` its time (s); ``meas`` (:data:`MEAS_WIDTH`,) holds what a real
  controller could read (layout below); ``ref`` (n_control, 12) the reference (``ilcforce.task``
  column layout) of which the law reads row k; ``gains`` the controller's packed gains;
  ``mem_prev`` (n_control, width) the learned memory of iteration j - 1 and ``mem_new`` that of
  iteration j (row k written only when ``write`` is True; rows before k, written at earlier samples
  of this iteration, may be read: that is how a law adapts within an iteration); ``diag``
  (:data:`DIAG_WIDTH`,) receives sigma for logging. The return value is the joint torque (N m).

  The law never integrates anything and never sees the true plant. It must be a polynomial of
  degree at most 2 in the acceleration ``meas[MEAS_ACCEL + force axis]`` (with
  ``meas[MEAS_FORCE_ACCEL + ...]`` following it through the stiffness relation): the simulator
  uses that to resolve the algebraic loop of docs/model.md#acceleration ("implicit" scheme). The contract test
  checks this for every registered law.

* a Python **object** implementing :class:`Controller`: it packs the gains, owns the learned memory
  between iterations, and names it for the store. Its ``end_iteration(record)`` receives the
  finished iteration's :class:`~ilcforce.records.IterationRecord`, so a law may learn between
  iterations (trial to trial) as well as at each sample.

Gains are packed by name: :func:`gain_indices` derives each field's index in the packed vector from
the gains dataclass (shared prefix first, then the dataclass fields in declaration order), and
:func:`pack_gains` fills the vector in the same order, so a law reads ``gains[ETA]``, never a
hand-counted offset. A law is compiled only when first used (:class:`compiled_law`), so importing a
method module loads no kernel.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import G_OWN_FIRST, at_py, compile_law, field_width

if TYPE_CHECKING:
    from ilcforce.records import IterationRecord

# --- measurement vector handed to a law (filled by the simulator) ----------------------------
MEAS_THETA = 0  # measured joint angles theta1, theta2 (rad)
MEAS_DTHETA = 2  # measured joint rates (rad/s)
MEAS_FORCE = 4  # measured contact force F (x, y), N, task.Wall convention
MEAS_POSITION = 6  # P from the nominal kinematics of the measured angles (m)
MEAS_VELOCITY = 8  # dP/dt = J dtheta from the measured rates (m/s)
MEAS_JACOBIAN = 10  # nominal J at the measured angles: J00, J01, J10, J11
MEAS_ACCEL = 14  # end-effector acceleration estimate (x, y), m/s^2 (scheme dependent)
MEAS_FORCE_RATE = 16  # dF/dt estimate (x, y), N/s
MEAS_FORCE_ACCEL = 18  # d2F/dt2 estimate (x, y), N/s^2
MEAS_TASK_INERTIA = 20  # nominal D at the measured state: D00, D01, D11 (only if requested)
MEAS_TASK_CORIOLIS = 23  # nominal C at the measured state: C00, C01, C10, C11 (only if requested)
MEAS_TASK_GRAVITY = 27  # nominal G = J^-T G_q at the measured angles: Gx, Gy (only if requested)
MEAS_WIDTH = 29

DIAG_SIGMA = 0
DIAG_WIDTH = 2

# --- gains shared by every law (eq. 8 and the force feed-forward sign) -----------------------
GAIN_SELECTION = 0  # s: 1 on force-controlled axes (S = diag(s), Sbar = I - S)
GAIN_LAMBDA_P = 2  # lambda_P diagonal
GAIN_LAMBDA_F1 = 4  # lambda_F1 diagonal
GAIN_LAMBDA_F2 = 6  # lambda_F2 diagonal
GAIN_FEEDFORWARD_SIGN = 8  # w of task.Wall: +1 adds +F (docs/model.md#wall), -1 the paper's -F
GAIN_OWN_FIRST = 9  # first index of a controller's own gains



@functools.cache
def law_signature():
    """:data:`LAW_SIGNATURE` (imports numba)."""
    types = _jit.numba().types
    return types.UniTuple(types.float64, 2)(
        types.int64,
        types.float64,
        types.float64[::1],
        types.float64[:, ::1],
        types.float64[::1],
        types.float64[:, ::1],
        types.float64[:, ::1],
        types.boolean,
        types.float64[::1],
    )


def __getattr__(name: str):
    """``LAW_SIGNATURE`` (the numba signature of every law) and ``LAW_TYPE`` (its first-class
    function type), built on first use: importing this module does not import numba."""
    if name == "LAW_SIGNATURE":
        return law_signature()
    if name == "LAW_TYPE":
        return _jit.numba().types.FunctionType(law_signature())
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@njit(cache=True, error_model="numpy")
def sgn(x):
    """Signum with sgn(0) = 0 (docs/model.md#surface)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, error_model="numpy")
def _axis_terms(i, k, meas, ref, gains, psi_desired):
    s = gains[GAIN_SELECTION + i]
    sbar = 1.0 - s
    e_p = sbar * (ref[k, 0 + i] - meas[MEAS_POSITION + i])  # eq. (6)
    de_p = sbar * (ref[k, 2 + i] - meas[MEAS_VELOCITY + i])
    e_f = s * (ref[k, 6 + i] - meas[MEAS_FORCE + i])  # eq. (7)
    de_f = s * (ref[k, 8 + i] - meas[MEAS_FORCE_RATE + i])
    dde_f = s * (ref[k, 10 + i] - meas[MEAS_FORCE_ACCEL + i])
    lp = gains[GAIN_LAMBDA_P + i]
    lf1 = gains[GAIN_LAMBDA_F1 + i]
    lf2 = gains[GAIN_LAMBDA_F2 + i]
    sigma = lp * e_p + de_p + lf1 * e_f + lf2 * de_f  # eq. (8)
    acc = ref[k, 4 + i] if psi_desired else meas[MEAS_ACCEL + i]
    psi1 = lp * de_p + lf1 * de_f + lf2 * dde_f + sbar * ref[k, 4 + i] + s * acc  # eq. (12), first block
    psi2 = meas[MEAS_VELOCITY + i] + sigma  # eq. (12), second block
    return sigma, psi1, psi2


@njit(cache=True, error_model="numpy")
def surface_terms(k, meas, ref, gains, psi_desired):
    """Errors, the sliding surface (eq. 8) and the regressor inputs of eq. (12), per task axis.

    Returns (sigma_x, sigma_y, psi1_x, psi1_y, psi2_x, psi2_y) where
    sigma = lambda_P e_P + de_P + lambda_F1 e_F + lambda_F2 de_F                     (eq. 8)
    psi1 = lambda_P de_P + lambda_F1 de_F + lambda_F2 dde_F + Sbar ddP_d + S ddP        (eq. 12)
    psi2 = dP + sigma                                                                (eq. 12)
    With ``psi_desired`` the S ddP term uses the desired acceleration S ddP_d instead (docs/model.md#acceleration).
    """
    sx, p1x, p2x = _axis_terms(0, k, meas, ref, gains, psi_desired)
    sy, p1y, p2y = _axis_terms(1, k, meas, ref, gains, psi_desired)
    return sx, sy, p1x, p1y, p2x, p2y


@njit(cache=True, error_model="numpy")
def joint_torque(meas, ux, uy):
    """tau = J^T u for a task-space command u (N), with the nominal J at the measured angles."""
    J00 = meas[MEAS_JACOBIAN]
    J01 = meas[MEAS_JACOBIAN + 1]
    J10 = meas[MEAS_JACOBIAN + 2]
    J11 = meas[MEAS_JACOBIAN + 3]
    return J00 * ux + J10 * uy, J01 * ux + J11 * uy


@njit(cache=True, error_model="numpy")
def nominal_gravity(meas, scale):
    """``scale`` G_nom (N), the nominal task-space gravity at the measured angles, per axis; (0, 0)
    when ``scale`` is 0 (MEAS_TASK_GRAVITY is then not filled, so it is not read)."""
    if scale == 0.0:
        return 0.0, 0.0
    return scale * meas[MEAS_TASK_GRAVITY], scale * meas[MEAS_TASK_GRAVITY + 1]


def check_gravity_feedforward(section: str, value) -> None:
    """g_ff: a finite number >= 0 (1 = the nominal model's gravity; 0 = none, the paper's laws)."""
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{section}.gravity_feedforward must be finite and >= 0, got {value!r}")


def pack_common_gains(surface, wall_sign: float) -> list[float]:
    """The shared prefix of every law's gain vector (indices GAIN_SELECTION .. GAIN_OWN_FIRST - 1)."""
    values = [*surface.selection, *surface.lambda_p, *surface.lambda_f1, *surface.lambda_f2, wall_sign]
    assert len(values) == at_py(G_OWN_FIRST, len(surface.selection))
    return [float(v) for v in values]


def _field_width(value) -> int:
    return len(value) if isinstance(value, tuple) else 1


def gain_layout(gains_cls, derived: tuple[str, ...] = (), n: int = 2) -> dict[str, slice]:
    """Where each gain lives in the packed vector: field name -> slice.

    The fields of ``gains_cls`` (a dataclass whose defaults fix each field's 2-D width) follow the
    shared prefix in declaration order; ``derived`` names one-number entries the controller
    computes (e.g. the sample time) and appends after them. For a task of ``n`` axes the prefix and
    each field are as wide as ``ilcforce.controllers.nd`` says (the same layout for n = 2).
    """
    layout, start = {}, GAIN_OWN_FIRST if n == 2 else at_py(G_OWN_FIRST, n)
    for f in dataclasses.fields(gains_cls):
        width = field_width(gains_cls, f.name, n)
        layout[f.name] = slice(start, start + width)
        start += width
    for name in derived:
        layout[name] = slice(start, start + 1)
        start += 1
    return layout


def gain_indices(gains_cls, *names: str, derived: tuple[str, ...] = ()) -> tuple[int, ...]:
    """First index of each named gain, for module-level constants a compiled law reads.

    ``names`` must list every field of ``gains_cls`` and then every ``derived`` entry, in order, so
    that a field added to the dataclass cannot be forgotten by the law module.
    """
    layout = gain_layout(gains_cls, derived)
    if tuple(layout) != names:
        raise TypeError(f"{gains_cls.__name__}: gain names {names} must be the fields then the derived "
                        f"entries, in order: {tuple(layout)}")
    return tuple(layout[n].start for n in names)


def pack_gains(surface, wall_sign: float, gains, *, encode: Mapping[str, Mapping[str, float]] | None = None,
               derived: Mapping[str, float] | None = None) -> np.ndarray:
    """The packed gain vector of :func:`gain_layout`: shared prefix, the dataclass fields, ``derived``.

    ``encode`` maps a text field to its number (e.g. ``{"psi_acceleration": {"measured": 0.0, ...}}``).
    A field whose width differs from the dataclass default's raises ValueError naming it (the law's
    indices would be wrong).
    """
    encode = encode or {}
    derived = dict(derived or {})
    n = len(surface.selection)
    layout = gain_layout(type(gains), tuple(derived), n)
    values = pack_common_gains(surface, wall_sign)
    for f in dataclasses.fields(gains):
        value = getattr(gains, f.name)
        if f.name in encode:
            value = encode[f.name][value]
        width = layout[f.name].stop - layout[f.name].start
        if _field_width(value) != width:
            raise ValueError(f"{f.name} must have {width} entries for this law on a task of {n} axes, "
                             f"got {_field_width(value)}")
        values += [float(v) for v in value] if isinstance(value, tuple) else [float(value)]
    values += [float(v) for v in derived.values()]
    return np.array(values, dtype=np.float64)


class compiled_law:  # noqa: N801 (used as a decorator-like descriptor)
    """A law function compiled with :data:`LAW_SIGNATURE` on first access, then cached.

    ``law = compiled_law(my_law)`` as a controller class attribute: ``Controller.law`` and
    ``controller.law`` return the numba dispatcher, so only the methods a process runs load (or
    compile) their kernels. numba's on-disk cache works as with the decorator.
    """

    def __init__(self, py_func: Callable):
        self.py_func = py_func
        self._dispatcher = None

    def dispatcher(self):
        if self._dispatcher is None:
            self._dispatcher = compile_law(self.py_func, law_signature())  # LawError if it does not compile
        return self._dispatcher

    def __get__(self, obj, owner=None):
        return self.dispatcher()


@runtime_checkable
class Controller(Protocol):
    """What the iteration loop needs from a method. See the module docstring."""

    name: str
    #: the compiled law, a numba dispatcher with LAW_SIGNATURE
    law: object
    #: True if the law reads MEAS_TASK_INERTIA / _CORIOLIS / _GRAVITY (the simulator fills them)
    uses_nominal_dynamics: bool

    def gains(self) -> np.ndarray:
        """Packed gains, shape (n_gains,)."""

    def begin_iteration(self, iteration: int) -> tuple[np.ndarray, np.ndarray]:
        """Memory buffers (mem_prev, mem_new) for iteration j, each (n_control, width)."""

    def end_iteration(self, record: IterationRecord) -> None:
        """After iteration j, given its record: the memory iteration j + 1 learns from is made."""

    def learned_state(self) -> dict[str, np.ndarray]:
        """Named arrays of the memory after the last finished iteration (control grid), which the
        controller does not write again (copies, or views of a buffer no later iteration reuses)."""

    def unfinished_state(self) -> dict[str, np.ndarray]:
        """Named copies of the memory an unfinished (diverged) iteration was writing."""

    def learned_units(self) -> dict[str, str]:
        """Unit of each entry of learned_state()."""

    def restore(self, memory: dict[str, np.ndarray]) -> None:
        """Load a stored learned_state() (for --resume)."""


class MemoryController:
    """Shared machinery for controllers whose memory is an (n_control, width) array.

    Subclasses set ``name``, ``law``, ``uses_nominal_dynamics``, ``memory_layout``
    (name -> (first column, last column + 1, unit); a one-column block is stored as a vector)
    and implement ``gains()``. ``sample_time`` (s) is the control period, for laws that integrate
    or filter over time.
    """

    name = ""
    law = None
    uses_nominal_dynamics = False
    memory_layout: dict[str, tuple[int, int, str]] = {}

    def __init__(self, n_control: int, sample_time: float = float("nan")):
        width = max((stop for _, stop, _ in self.memory_layout.values()), default=0)
        self.n_control = int(n_control)
        self.sample_time = float(sample_time)
        self._prev = np.zeros((self.n_control, width))  # memory of j - 1 (zero before j = 0)
        self._new = np.zeros((self.n_control, width))

    def begin_iteration(self, iteration: int) -> tuple[np.ndarray, np.ndarray]:
        # a fresh buffer for every iteration: the memory a finished iteration wrote is never written
        # again, so learned_state() hands it out without a copy (1.4 MB and 0.3 ms between two
        # iterations of the paper's C3). NaN marks a sample the law never reached.
        self._new = np.full(self._prev.shape, np.nan)
        return self._prev, self._new

    def end_iteration(self, record: IterationRecord) -> None:
        """A complete iteration's memory becomes the one iteration j + 1 reads (no-op if diverged)."""
        if not record.diverged:
            self._prev = self._new

    def _named(self, memory: np.ndarray, copy: bool) -> dict[str, np.ndarray]:
        out = {}
        for key, (start, stop, _unit) in self.memory_layout.items():
            block = memory[:, start:stop]
            block = block[:, 0] if stop - start == 1 else block
            if copy:
                block = block.copy()
            else:  # the next iteration reads this buffer as mem_prev: a record must not write it
                block = block.view()
                block.flags.writeable = False
            out[key] = block
        return out

    def learned_state(self) -> dict[str, np.ndarray]:
        """Read-only views of the last finished iteration's memory, which nothing writes again (a
        later iteration writes a buffer of its own; :meth:`restore` makes a new one). Subclasses must
        not write ``_prev`` in place: it is handed out, and read by the next iteration."""
        return self._named(self._prev, copy=False)

    def unfinished_state(self) -> dict[str, np.ndarray]:
        """The memory a diverged iteration was writing (NaN where it never got)."""
        return self._named(self._new, copy=True)

    def learned_units(self) -> dict[str, str]:
        return {key: unit for key, (_a, _b, unit) in self.memory_layout.items()}

    #: optional column labels of a memory block: name -> one label per column
    memory_labels: dict[str, tuple[str, ...]] = {}

    def learned_labels(self) -> dict[str, tuple[str, ...]]:
        """Column labels of each multi-column memory block (those given in ``memory_labels``)."""
        return {key: tuple(labels) for key, labels in self.memory_labels.items()
                if key in self.memory_layout
                and len(labels) == self.memory_layout[key][1] - self.memory_layout[key][0]}

    def restore(self, memory: dict[str, np.ndarray]) -> None:
        for key, (start, stop, _unit) in self.memory_layout.items():
            if key not in memory:
                raise ValueError(f"stored memory lacks {key!r} needed by {self.name}")
            block = np.asarray(memory[key], dtype=np.float64).reshape(self.n_control, stop - start)
            self._prev = self._prev.copy()  # what learned_state() gave out before stays as it was
            self._prev[:, start:stop] = block


def check_vector(name: str, value, length: int) -> tuple[float, ...]:
    """A finite numeric vector of the given length, or ValueError naming ``name``."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of {length} numbers, got {value!r}") from None
    if arr.shape != (length,):
        raise ValueError(f"{name} must have {length} entries, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return tuple(float(v) for v in arr)

