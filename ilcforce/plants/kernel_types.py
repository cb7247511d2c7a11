"""The signatures of a planar plant's five tuple kernels (``ilcforce.plants.base.PlantKernels``): what each takes
and returns, as numba types made on first use (importing this module does not import numba). Their own module so
that the kernels' users (the plant base class, the compiled tau_d of ``ilcforce.plants.desired``) import it
without importing each other.
"""

from __future__ import annotations

import functools

from ilcforce.compiled import jit as _jit

__all__ = ["kernel_signature", "kernel_type"]

#: the kernels' outputs (a tuple of this many floats) and scalar inputs after ``p``, in
#: PlantKernels order; their numba signatures are made on first use (importing this module does
#: not import numba): ``KIN_SIGNATURE`` ... and the first-class function types ``KIN_TYPE`` ...
_SHAPES = {"KIN": (7, 2), "ACCEL": (14, 4), "TASK": (18, 4), "DYN": (20, 4), "IK": (3, 2)}


@functools.cache
def kernel_signature(kind: str):
    """The numba signature of kernel ``kind`` ("KIN", "ACCEL", "TASK", "DYN" or "IK")."""
    types = _jit.numba().types
    n_out, n_in = _SHAPES[kind]
    return types.UniTuple(types.float64, n_out)(types.intp, *([types.float64] * n_in))


def kernel_type(kind: str):
    """The first-class function type of kernel ``kind``, as compiled code takes it (the planar tau_d kernel)."""
    return _jit.numba().types.FunctionType(kernel_signature(kind))


def __getattr__(name: str):
    kind, _, suffix = name.partition("_")
    if kind in _SHAPES and suffix == "SIGNATURE":
        return kernel_signature(kind)
    if kind in _SHAPES and suffix == "TYPE":
        return kernel_type(kind)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
