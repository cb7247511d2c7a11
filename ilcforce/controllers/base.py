"""The one contract every controller implements, and the parts all of them share.

A controller has two halves:

* a compiled **law**, called by the simulation loop at every control sample. Its signature is fixed
  (:func:`ilcforce.controllers.nd.law_signature`) so that the loop is compiled and cached once and calls any
  law through a function pointer::

      law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau) -> 0

  The task has n axes (n joints, non-redundant): n = 2 for the planar robots, 3 for the spatial arm, and
  one compiled law serves every n (it reads n = tau.shape[0]). ``k`` is the control sample, ``t`` its time
  (s); ``meas`` holds what a real controller could read, in the task frame, and ``ref`` (n_control, 6 n)
  the reference (``ilcforce.task`` column layout) of which the law reads row k, each in the layout of
  :mod:`ilcforce.controllers.nd` (an offset a + b n + c n^2 per block); ``gains`` the controller's packed
  gains; ``mem_prev`` (n_control, width) the learned memory of iteration j - 1 and ``mem_new`` that of
  iteration j (row k written only when ``write`` is True; rows before k, written at earlier samples of
  this iteration, may be read: that is how a law adapts within an iteration); ``diag`` receives sigma in
  its first n entries (for logging) and is the law's scratch after them; ``tau`` (n,) receives the joint
  torque (N m).

  The law never integrates anything and never sees the true plant. It must be a polynomial of
  degree at most 2 in the acceleration ``meas[at(M_ACCEL, n) + force axis]`` (with
  ``meas[at(M_FORCE_ACCEL, n) + ...]`` following it through the stiffness relation): the simulator
  uses that to resolve the algebraic loop of docs/model.md#acceleration ("implicit" scheme). The contract
  test checks this for every registered law.

* a Python **object** implementing :class:`Controller`: it packs the gains, owns the learned memory
  between iterations, and names it for the store. Its ``end_iteration(record)`` receives the
  finished iteration's :class:`~ilcforce.records.IterationRecord`, so a law may learn between
  iterations (trial to trial) as well as at each sample.

Gains are packed by name: :func:`ilcforce.controllers.nd.gain_offsets` derives each field's offset triple
from the gains dataclass (shared prefix first, then the dataclass fields in declaration order), and
:func:`pack_gains` fills the vector in the same order, so a law reads ``gains[at(ETA, n)]``, never a
hand-counted offset. A law is compiled only when first used (:class:`ilcforce.controllers.nd.compiled_law`),
so importing a method module loads no kernel.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from ilcforce.compiled.jit import njit
from ilcforce.controllers.nd import G_OWN_FIRST, at_py, field_width

if TYPE_CHECKING:
    from ilcforce.records import IterationRecord


@njit(cache=True, error_model="numpy")
def sgn(x):
    """Signum with sgn(0) = 0 (docs/model.md#surface)."""
    if x > 0.0:
        return 1.0
    if x < 0.0:
        return -1.0
    return 0.0


def check_gravity_feedforward(section: str, value) -> None:
    """g_ff: a finite number >= 0 (1 = the nominal model's gravity; 0 = none, the paper's laws)."""
    if not (np.isfinite(value) and value >= 0):
        raise ValueError(f"{section}.gravity_feedforward must be finite and >= 0, got {value!r}")


def pack_common_gains(surface, wall_sign: float) -> list[float]:
    """The shared prefix of every law's gain vector (offsets G_SELECTION .. G_OWN_FIRST - 1 of
    ``ilcforce.controllers.nd``)."""
    values = [*surface.selection, *surface.lambda_p, *surface.lambda_f1, *surface.lambda_f2, wall_sign]
    assert len(values) == at_py(G_OWN_FIRST, len(surface.selection))
    return [float(v) for v in values]


def _field_width(value) -> int:
    return len(value) if isinstance(value, tuple) else 1


def gain_layout(gains_cls, n: int = 2) -> dict[str, slice]:
    """Where each gain lives in the packed vector of a task of ``n`` axes: field name -> slice.

    The fields of ``gains_cls`` follow the shared prefix in declaration order, each as wide as
    ``ilcforce.controllers.nd.field_width`` says (where ``gain_offsets`` puts them for the law).
    """
    layout, start = {}, at_py(G_OWN_FIRST, n)
    for f in dataclasses.fields(gains_cls):
        width = field_width(gains_cls, f.name, n)
        layout[f.name] = slice(start, start + width)
        start += width
    return layout


def pack_gains(surface, wall_sign: float, gains, *,
               encode: Mapping[str, Mapping[str, float]] | None = None) -> np.ndarray:
    """The packed gain vector of :func:`gain_layout`: the shared prefix, then the dataclass fields.

    ``encode`` maps a text field to its number (e.g. ``{"psi_acceleration": {"measured": 0.0, ...}}``).
    A field whose width differs from the one the task's axes need raises ValueError naming it (the law's
    offsets would be wrong).
    """
    encode = encode or {}
    n = len(surface.selection)
    layout = gain_layout(type(gains), n)
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
    return np.array(values, dtype=np.float64)


def law_of(controller):
    """The compiled law of ``controller``: the one set on the object itself, else its class's, read from the class
    (a numba dispatcher set on a class would be bound to the object, as a method, if read from the object)."""
    own = getattr(controller, "__dict__", {}).get("law")
    return own if own is not None else type(controller).law


@runtime_checkable
class Controller(Protocol):
    """What the iteration loop needs from a method. See the module docstring."""

    name: str
    #: the compiled law, a numba dispatcher with ``ilcforce.controllers.nd.law_signature`` (module docstring)
    law: object
    #: True if the law reads M_TASK_INERTIA / _CORIOLIS / _GRAVITY (the simulator fills them)
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

