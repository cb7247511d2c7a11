"""Arrays without an owner, for the hot path of compiled loops: views of memory someone else keeps alive.

numba counts references to every array it passes: each array argument of a called function (and of a
function inlined into the caller) is increfed on entry and decrefed on exit, an atomic operation on the
array's owner. The simulation loop passes some forty arrays per control sample to the plant, the law and its
helpers, and those counts cost more than the arithmetic: one RK4 stage of the five-bar took 186 ns with owned
scratch arrays and 76 ns with these views (measured in one process, minimum of five rounds of a million
stages). A view made here has no owner (numba skips the count), so it is valid only while the array it was
made from is: within the compiled call that made it, from arrays that call received or allocated.
"""

from __future__ import annotations

from ilcforce.compiled import jit as _jit
from ilcforce.compiled.jit import intrinsic, njit, numba_global

__all__ = ["address_to_pointer", "carray", "unowned", "unowned_matrix", "scratch", "carve"]

carray = numba_global("carray")


@intrinsic
def address_to_pointer(typingctx, address):
    """An integer address as a float64 pointer (no reference counting, no bounds)."""
    types = _jit.numba().types
    sig = types.CPointer(types.float64)(address)

    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], context.get_value_type(signature.return_type))

    return sig, codegen


@njit(cache=True, error_model="numpy", inline="always")
def unowned(a):
    """A view of the float64 vector ``a`` without an owner."""
    return carray(address_to_pointer(a.ctypes.data), a.shape[0])


@njit(cache=True, error_model="numpy", inline="always")
def unowned_matrix(a):
    """A view of the C-contiguous float64 matrix ``a`` without an owner."""
    return carray(address_to_pointer(a.ctypes.data), (a.shape[0], a.shape[1]))


@njit(cache=True, error_model="numpy", inline="always")
def scratch(buffer, offset, length):
    """``buffer[offset:offset + length]`` as a view without an owner (``buffer`` a float64 vector)."""
    return carray(address_to_pointer(buffer.ctypes.data + 8 * offset), length)


@njit(cache=True, error_model="numpy", inline="always")
def carve(buffer, offset, length):
    """(:func:`scratch` of ``length`` floats at ``offset``, the offset after it): the next view carved from a
    buffer, so that a run of carvings reads one line each (``x, o = carve(work, o, n)``)."""
    return scratch(buffer, offset, length), offset + length
