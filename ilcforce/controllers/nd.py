"""The control laws' contract (docs/model.md#n-dof): what the simulation loop gives a law and takes back, for a
task of n axes (n joints, non-redundant; n = 2 for the planar robots, 3 for the spatial arm). The contract as a
whole (the law and the controller object around it) is described in :mod:`ilcforce.controllers.base`; this
module holds the law's signature and layouts and the terms every law shares::

    law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau) -> 0

``tau`` (n,) receives the joint torque (N m); ``diag`` (:func:`diag_width` (n),) receives sigma in its
first n entries and is the law's scratch space after them. ``meas`` holds the blocks below, each at an
offset a + b n + c n^2 (so that one compiled law serves every n); matrices are n x n, row-major, in the
task frame (the wall's frame, docs/model.md#wall-plane; the identity for a planar robot). ``ref`` is
(n_control, 6 n): P_d, dP_d, ddP_d, F_d, dF_d, ddF_d, n columns each. ``gains`` starts with the shared
prefix (selection, lambda_P, lambda_F1, lambda_F2: n each; the feed-forward sign w), then the method's own
fields in declaration order, each as wide as :func:`field_width` says.

Every offset is a triple (a, b, c) read with :func:`at`; the laws read them as compile-time constants.
"""

from __future__ import annotations

import dataclasses
import functools
import re

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit

# --- measurement vector: (a, b, c) -> offset a + b n + c n^2 -------------------------------------
M_THETA = (0, 0, 0)  # measured joint angles (n)
M_DTHETA = (0, 1, 0)  # measured joint rates (n)
M_FORCE = (0, 2, 0)  # measured contact force in the task frame (n), N
M_POSITION = (0, 3, 0)  # X = R P from the nominal kinematics (n), m
M_VELOCITY = (0, 4, 0)  # dX/dt = J_X dtheta (n), m/s
M_JACOBIAN = (0, 5, 0)  # nominal J_X = R J (n x n)
M_ACCEL = (0, 5, 1)  # acceleration estimate (n), m/s^2
M_FORCE_RATE = (0, 6, 1)  # dF/dt estimate (n), N/s
M_FORCE_ACCEL = (0, 7, 1)  # d2F/dt2 estimate (n), N/s^2
M_TASK_INERTIA = (0, 8, 1)  # nominal D (n x n), only if the law asks for the nominal dynamics
M_TASK_CORIOLIS = (0, 8, 2)  # nominal C (n x n), idem
M_TASK_GRAVITY = (0, 8, 3)  # nominal G (n), idem
M_WIDTH = (0, 9, 3)

# --- reference columns (blocks of n) -------------------------------------------------------------
R_POSITION, R_VELOCITY, R_ACCELERATION, R_FORCE, R_FORCE_RATE, R_FORCE_ACCEL = 0, 1, 2, 3, 4, 5
REF_BLOCKS = 6

# --- shared gain prefix ----------------------------------------------------------------------------
G_SELECTION = (0, 0, 0)
G_LAMBDA_P = (0, 1, 0)
G_LAMBDA_F1 = (0, 2, 0)
G_LAMBDA_F2 = (0, 3, 0)
G_FEEDFORWARD_SIGN = (0, 4, 0)
G_OWN_FIRST = (1, 4, 0)

# --- diag: sigma, then the laws' scratch: psi1, psi2 (eq. 12), the task command u ------------------
D_SIGMA, D_PSI1, D_PSI2, D_U = (0, 0, 0), (0, 1, 0), (0, 2, 0), (0, 3, 0)


def diag_width(n: int) -> int:
    return 4 * n


def at_py(offset: tuple[int, int, int], n: int) -> int:
    a, b, c = offset
    return a + b * n + c * n * n


@njit(inline="always", error_model="numpy")
def at(offset, n):
    """The offset a + b n + c n^2 of a layout triple."""
    return offset[0] + offset[1] * n + offset[2] * n * n


#: how a gains field's width grows with n, from its default's width (the defaults are written for the planar
#: task, n = 2): a number stays one; a per-axis vector (2 entries) has n; a per-axis-pair block (4 entries:
#: C3's G block) n^2; C3's D and C blocks (8 entries: 2 per axis pair) 2 n^2
_GROWTH = {1: (1, 0, 0), 2: (0, 1, 0), 4: (0, 0, 1), 8: (0, 0, 2)}


def field_growth(gains_cls) -> dict[str, tuple[int, int, int]]:
    """Each field of a gains dataclass -> its width as a triple (a, b, c) (width a + b n + c n^2)."""
    out = {}
    for f in dataclasses.fields(gains_cls):
        value = f.default  # the planar task's default (not an instance: making one runs the checks that call this)
        width = len(value) if isinstance(value, tuple) else 1
        out[f.name] = _GROWTH.get(width, (width, 0, 0))  # any other width: a list of its own length (sl-adapt's Gamma)
    return out


def field_width(gains_cls, name: str, n: int) -> int:
    return at_py(field_growth(gains_cls)[name], n)


def gain_offsets(gains_cls, *names: str) -> tuple[tuple[int, int, int], ...]:
    """The offset triple of each named field: ``names`` must list every field of ``gains_cls`` in order, so that
    a field added to the dataclass cannot be forgotten by the law module."""
    growth = field_growth(gains_cls)
    if tuple(growth) != names:
        raise TypeError(f"{gains_cls.__name__}: gain names {names} must be the fields in order: {tuple(growth)}")
    out, start = [], G_OWN_FIRST
    for name in names:
        out.append(start)
        start = tuple(s + g for s, g in zip(start, growth[name]))
    return tuple(out)


def dimension_of(gains) -> int:
    """The task dimension n a gains object was written for (from its first per-axis field)."""
    for name, growth in field_growth(type(gains)).items():
        if growth == (0, 1, 0):
            return len(getattr(gains, name))
    return 0


def check_widths(section: str, gains, n: int | None = None) -> int:
    """Every field of ``gains`` as wide as a task of ``n`` axes needs (default: the n its first per-axis field
    implies); returns n (ValueError, one line, naming the first field that is not). The gains dataclasses check
    themselves with it, the configuration against its task's axes. A field the gains class lists in
    ``plant_sized`` is as wide as the plant says; its controller checks it."""
    given = n is not None
    n = dimension_of(gains) if n is None else n
    if n < 1:
        return n
    first = next(name for name, growth in field_growth(type(gains)).items() if growth == (0, 1, 0))
    why = f"a task of {n} axes" if given else f"a task of {n} axes, as {section}.{first} has {n} entries"
    plant_sized = getattr(type(gains), "plant_sized", ())
    for name, growth in field_growth(type(gains)).items():
        if name in plant_sized:  # as wide as the plant says (sl-adapt's Gamma: its base parameters)
            continue
        value = getattr(gains, name)
        width = len(value) if isinstance(value, tuple) else 1
        want = at_py(growth, n)
        if width != want:
            raise ValueError(f"{section}.{name} must have {want} entries for {why}, got {width}")
    return n


class LawError(ValueError):
    """A law numba cannot compile, in one line naming it (a shipped law always compiles; a plugin's may not,
    docs/plugins.md)."""

    @classmethod
    def of(cls, py_func, exc: Exception) -> LawError:
        """The error for ``py_func`` from numba's (several lines, the first a generic "Failed in ...")."""
        lines = [re.sub(r"\x1b\[[0-9;]*m", "", line).strip() for line in str(exc).splitlines()]
        said = next((line for line in lines if line and not line.startswith("Failed in ")), type(exc).__name__)
        return cls(f"the law {py_func.__module__}.{py_func.__qualname__} does not compile with numba: {said[:300]}")


def compile_law(py_func, signature):
    """``numba.njit(signature, cache=True, error_model="numpy")(py_func)``; LawError if numba cannot compile it."""
    try:
        return _jit.numba().njit(signature, cache=True, error_model="numpy")(py_func)
    except Exception as exc:  # noqa: BLE001 - numba's typing and lowering errors have no common base
        raise LawError.of(py_func, exc) from None


@functools.cache
def law_signature():
    """The numba signature of every law (imports numba)."""
    types = _jit.numba().types
    return types.int64(
        types.int64, types.float64, types.float64[::1], types.float64[:, ::1], types.float64[::1],
        types.float64[:, ::1], types.float64[:, ::1], types.boolean, types.float64[::1], types.float64[::1],
    )


class compiled_law:  # noqa: N801 (used as a decorator-like descriptor)
    """A law function compiled with :func:`law_signature` on first access, then cached.

    ``law = compiled_law(my_law)`` as a controller class attribute: ``Controller.law`` and
    ``controller.law`` return the numba dispatcher, so only the methods a process runs load (or
    compile) their kernels. numba's on-disk cache works as with the decorator.
    """

    def __init__(self, py_func):
        self.py_func = py_func
        self._dispatcher = None

    def dispatcher(self):
        if self._dispatcher is None:
            self._dispatcher = compile_law(self.py_func, law_signature())  # LawError if it does not compile
        return self._dispatcher

    def __get__(self, obj, owner=None):
        return self.dispatcher()


# --- the shared terms --------------------------------------------------------------------------------

@njit(inline="always", error_model="numpy")
def surface(n, k, meas, ref, gains, psi_desired, diag):
    """The errors (eqs. 6-7), sigma (eq. 8) and Psi's blocks psi1, dP + sigma (eq. 12) per task axis, into diag
    (D_SIGMA, D_PSI1, D_PSI2):

    sigma = lambda_P e_P + de_P + lambda_F1 e_F + lambda_F2 de_F                     (eq. 8)
    psi1 = lambda_P de_P + lambda_F1 de_F + lambda_F2 dde_F + Sbar ddP_d + S ddP        (eq. 12)
    psi2 = dP + sigma                                                                (eq. 12)

    With ``psi_desired`` the S ddP term uses the desired acceleration S ddP_d instead (docs/model.md#acceleration)."""
    for i in range(n):
        s = gains[at(G_SELECTION, n) + i]
        sbar = 1.0 - s
        e_p = sbar * (ref[k, R_POSITION * n + i] - meas[at(M_POSITION, n) + i])  # eq. (6)
        de_p = sbar * (ref[k, R_VELOCITY * n + i] - meas[at(M_VELOCITY, n) + i])
        e_f = s * (ref[k, R_FORCE * n + i] - meas[at(M_FORCE, n) + i])  # eq. (7)
        de_f = s * (ref[k, R_FORCE_RATE * n + i] - meas[at(M_FORCE_RATE, n) + i])
        dde_f = s * (ref[k, R_FORCE_ACCEL * n + i] - meas[at(M_FORCE_ACCEL, n) + i])
        lp = gains[at(G_LAMBDA_P, n) + i]
        lf1 = gains[at(G_LAMBDA_F1, n) + i]
        lf2 = gains[at(G_LAMBDA_F2, n) + i]
        sigma = lp * e_p + de_p + lf1 * e_f + lf2 * de_f  # eq. (8)
        acc = ref[k, R_ACCELERATION * n + i] if psi_desired else meas[at(M_ACCEL, n) + i]
        diag[i] = sigma
        diag[n + i] = lp * de_p + lf1 * de_f + lf2 * dde_f + sbar * ref[k, R_ACCELERATION * n + i] + s * acc  # eq. (12)
        diag[2 * n + i] = meas[at(M_VELOCITY, n) + i] + sigma  # eq. (12), second block


@njit(inline="always", error_model="numpy")
def add_joint_torque(n, meas, u, u0, tau):
    """tau += J_X^T u for the task command u = u[u0:u0 + n] (N), J_X nominal at the measured angles."""
    J = at(M_JACOBIAN, n)
    for j in range(n):
        s = 0.0
        for i in range(n):
            s += meas[J + i * n + j] * u[u0 + i]
        tau[j] += s


@njit(inline="always", error_model="numpy")
def joint_torque(n, meas, u, u0, tau):
    """tau = J_X^T u[u0:u0 + n] (0 + s is s: the same numbers as assigning the sum)."""
    for j in range(n):
        tau[j] = 0.0
    add_joint_torque(n, meas, u, u0, tau)


@njit(inline="always", error_model="numpy")
def nominal_gravity(n, meas, scale, i):
    """scale G_nom,i (N); 0 when scale is 0 (the block is then not filled)."""
    if scale == 0.0:
        return 0.0
    return scale * meas[at(M_TASK_GRAVITY, n) + i]


@njit(inline="always", error_model="numpy")
def nominal_model_force(n, meas, diag, i):
    """(Xi_nom^T Psi)_i = (D_nom psi1 + C_nom (dP + sigma) + G_nom)_i (eqs. 11-12), psi1 and dP + sigma from diag."""
    D = at(M_TASK_INERTIA, n) + i * n
    C = at(M_TASK_CORIOLIS, n) + i * n
    s = 0.0
    for j in range(n):
        s += meas[D + j] * diag[n + j]
    for j in range(n):
        s += meas[C + j] * diag[2 * n + j]
    return s + meas[at(M_TASK_GRAVITY, n) + i]
