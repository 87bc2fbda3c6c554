"""Uniform draws of a numpy ``Generator`` from compiled code, without handing numba the Generator.

numba can take a ``numpy.random.Generator`` argument, but unboxing it on every call reads its
bit generator's function pointers through ``ctypes`` (about 9 us a call, more than typing forty
arrays). The robust loop's kernel is called a few times per estimate and only draws uniform
doubles, so it takes the two addresses instead (:func:`generator_address`, once per loop) and
calls the bit generator's own ``next_double`` on its own state (:func:`uniform_draws`): the
same C function numpy's ``Generator.random`` fills its arrays with, one value after the other in
C order, so the draws and the generator's state afterwards are numpy's to the bit.
"""

from __future__ import annotations

import ctypes

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.core.extending import intrinsic

__all__ = ["generator_address", "uniform_draws"]


def generator_address(rng: np.random.Generator) -> np.ndarray:
    """(2,) intp: the addresses of ``rng``'s bit generator's ``next_double`` and of its state.

    Valid while ``rng`` lives (the caller keeps it); setting its state keeps the address."""
    iface = rng.bit_generator.ctypes
    fn = ctypes.cast(iface.next_double, ctypes.c_void_p).value
    return np.array([fn, iface.state_address], dtype=np.intp)


@intrinsic
def _next_double(typingctx, fn, state):  # type: ignore[no-untyped-def]
    """double next_double(void *state) at address ``fn`` (intp), on the state at ``state``."""
    sig = types.float64(types.intp, types.intp)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        void_p = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.DoubleType(), [void_p])
        call = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(call, [builder.inttoptr(args[1], void_p)])

    return sig, codegen


@numba.njit(cache=True, nogil=True)
def uniform_draws(address: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """(rows, cols) uniform doubles in [0, 1): what ``Generator.random((rows, cols))`` returns,
    drawn from the generator at ``address`` (:func:`generator_address`), which advances."""
    out = np.empty((rows, cols))
    for i in range(rows):
        for j in range(cols):
            # (an intrinsic: numba supplies its typing context)
            out[i, j] = _next_double(address[0], address[1])  # type: ignore[call-arg]
    return out
