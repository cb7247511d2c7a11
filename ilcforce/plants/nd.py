"""The n-joint plant kernel interface: one compiled function per plant that an n-joint loop calls.

An n-joint loop calls a plant through ONE numba first-class function pointer of type :func:`nd_type`::

    nd_dyn(p: intp, q: float64[::1], dq: float64[::1], level: int64, out: float64[::1]) -> float64

``p`` is the address of the plant's packed parameter vector (as the 2-joint kernels take it,
``ilcforce.plants.base.params_view``); ``q`` and ``dq`` hold the n joint values and rates. The kernel
returns 1.0, or 0.0 when the pose is outside the plant's working mode, and writes into ``out``
(length >= :func:`nd_width` of the plant) at the offsets of :func:`offsets`, with n the plant's joint
count and its task dimension:

=========  ===============  =============================================================  ======
offset     value            what                                                           level
=========  ===============  =============================================================  ======
``p``      0                P (n): the end effector's position, world frame (m)            0
``j``      n                J (n x n, row-major): dP/dt = J dq                             0
``djv``    n + n^2          dJ/dt dq (n)                                                   1
``m``      2n + n^2         M(q), the joint inertia (n x n)                                1
``b``      2n + 2n^2        b = C(q, dq) dq + g(q) (n)                                     1
``cq``     3n + 2n^2        C(q, dq) (n x n), the Christoffel Coriolis matrix              2
``g``      3n + 3n^2        g(q) (n)                                                       2
``dj``     4n + 3n^2        dJ/dt (n x n)                                                  2
``width``  4n + 4n^2        the end of the interface: a plant's scratch space follows it
=========  ===============  =============================================================  ======

A kernel asked for ``level`` writes the entries of that level and every level below it, and
leaves the others as they were. Level 0 is kinematics, level 1 what forward dynamics needs
(M ddq = tau + J^T f - b), level 2 the task-space model of eq. (4).

:func:`offsets` also takes a task dimension other than n (``task``): then P, dJ/dt dq have
``task`` entries and J, dJ/dt ``task`` rows, everything else as above. An n-joint spatial chain
(``ilcforce.plants.chain_nd``) writes that layout with task = 3; it is the interface above when n = 3.

Importing this module does not import numba: the signature and the function type are made on
first use (as ``ilcforce.plants.base`` makes the 2-joint kernels' ones).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import njit

__all__ = ["Offsets", "offsets", "layout", "nd_layout", "nd_width", "nd_signature", "nd_type", "compile_nd",
           "from_dyn", "LEVEL_KINEMATICS", "LEVEL_DYNAMICS", "LEVEL_TASK_MODEL"]

#: the levels of ``nd_dyn``: kinematics; forward dynamics' terms; the task-space model's terms as well
LEVEL_KINEMATICS, LEVEL_DYNAMICS, LEVEL_TASK_MODEL = 0, 1, 2


def layout(n, task):
    """(p, j, djv, m, b, cq, g, dj, width): the offsets into ``out`` for n joints and a task of
    ``task`` dimensions (the interface's is task = n). Plain integer arithmetic, also compiled
    (:data:`nd_layout`) for a loop that sizes or reads ``out`` in compiled code."""
    p = 0
    j = p + task
    djv = j + task * n
    m = djv + task
    b = m + n * n
    cq = b + n
    g = cq + n * n
    dj = g + n
    width = dj + task * n
    return p, j, djv, m, b, cq, g, dj, width


#: :func:`layout` compiled, for numba code (``nd_layout(n, n)``)
nd_layout = njit(cache=True)(layout)


class Offsets(NamedTuple):
    """Where each quantity starts in ``out`` (see the module's table)."""

    p: int
    j: int
    djv: int
    m: int
    b: int
    cq: int
    g: int
    dj: int
    width: int


def offsets(n: int, task: int | None = None) -> Offsets:
    """The offsets into ``out`` for an ``n``-joint plant whose task has ``task`` dimensions (default n)."""
    if n < 1:
        raise ValueError(f"a plant has at least one joint, got n = {n}")
    return Offsets(*layout(int(n), int(n if task is None else task)))


def nd_width(plant) -> int:
    """The length ``out`` must have for ``plant``'s kernel: the interface's width for its joint count and
    task dimension, plus the scratch space its kernel uses (``plant.nd_joints``, ``plant.nd_task``,
    ``plant.nd_scratch``)."""
    return offsets(plant.nd_joints, plant.nd_task).width + plant.nd_scratch


@functools.cache
def nd_signature():
    """The numba signature of ``nd_dyn``."""
    types = _jit.numba().types
    vector = types.Array(types.float64, 1, "C")
    return types.float64(types.intp, vector, vector, types.int64, vector)


def nd_type():
    """The first-class function type of ``nd_dyn``, as a compiled loop takes it."""
    return _jit.numba().types.FunctionType(nd_signature())


def __getattr__(name: str):
    if name == "ND_SIGNATURE":
        return nd_signature()
    if name == "ND_TYPE":
        return nd_type()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def compile_nd(fn):
    """``fn(p, q, dq, level, out)`` compiled with the ``nd_dyn`` signature (or loaded from numba's on-disk
    cache, keyed by ``fn``'s own module)."""
    return _jit.numba().njit(nd_signature(), cache=True, error_model="numpy")(fn)


@njit(cache=True, error_model="numpy")
def from_dyn(dyn, d1, d2, level, out):
    """Write a 2-joint plant's DYN tuple (``ilcforce.plants.base``: ok, P, J, dJ, Dq (00, 01, 11), Cq, G_q)
    at joint rates (d1, d2) into ``out`` at the offsets of :func:`offsets` (n = 2) up to ``level``;
    return ok. Every entry is the DYN entry itself (Dq01 in both off-diagonal places) but
    dJ/dt dq = (dJ00 d1 + dJ01 d2, dJ10 d1 + dJ11 d2) and b = (Cq00 d1 + Cq01 d2 + G1, Cq10 d1 + Cq11 d2 + G2)."""
    (ok, px, py, J00, J01, J10, J11, dJ00, dJ01, dJ10, dJ11,
     Dq00, Dq01, Dq11, Cq00, Cq01, Cq10, Cq11, G1, G2) = dyn
    out[0] = px  # P
    out[1] = py
    out[2] = J00  # J
    out[3] = J01
    out[4] = J10
    out[5] = J11
    if level >= 1:
        out[6] = dJ00 * d1 + dJ01 * d2  # dJ dq
        out[7] = dJ10 * d1 + dJ11 * d2
        out[8] = Dq00  # M
        out[9] = Dq01
        out[10] = Dq01
        out[11] = Dq11
        out[12] = Cq00 * d1 + Cq01 * d2 + G1  # b = Cq dq + G_q
        out[13] = Cq10 * d1 + Cq11 * d2 + G2
    if level >= 2:
        out[14] = Cq00  # Cq
        out[15] = Cq01
        out[16] = Cq10
        out[17] = Cq11
        out[18] = G1  # G_q
        out[19] = G2
        out[20] = dJ00  # dJ
        out[21] = dJ01
        out[22] = dJ10
        out[23] = dJ11
    return ok
