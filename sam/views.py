"""Borrowed views for the hot loops: a row or a matrix of a C-contiguous array without
reference counting.

A numba view such as ``params[i]``, or a local array handed to an inlined function,
increments and later decrements its owner's reference count: two atomic instructions. Where
the loop body branches (end stops, cavitation clamps) numba cannot always prune the pair, and
in :func:`sam.step_batch` they were half the time of a step: measured 101 ns per sigma point
with ordinary views, 52 ns with these, identical results (2026-11-21, docs/benchmarks.md).

A borrowed view has no owner (its meminfo is NULL, which the reference counting skips): it
is valid only while the array it was taken from is alive, and must not be returned from or
stored beyond the function that took it.
"""

from __future__ import annotations

import numba
from numba import types
from llvmlite import ir
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic

jit_inline = numba.njit(cache=True, inline="always", error_model="numpy")


@intrinsic
def _item_pointer(typingctx, a, i):
    """Pointer to a[i, 0, ..., 0] of a C-contiguous array (numba intrinsic)."""
    if not isinstance(a, types.Array) or a.layout != "C":
        raise TypingError(f"borrowed views need a C-contiguous array (np.ascontiguousarray), got {a}")
    sig = types.CPointer(a.dtype)(a, i)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        ary = context.make_array(aryty)(context, builder, args[0])
        index = [context.cast(builder, args[1], signature.args[1], types.intp)]
        index += [context.get_constant(types.intp, 0)] * (aryty.ndim - 1)
        return cgutils.get_item_pointer2(context, builder, ary.data, cgutils.unpack_tuple(builder, ary.shape),
                                         cgutils.unpack_tuple(builder, ary.strides), aryty.layout, index)

    return sig, codegen


@jit_inline
def row(a, i):
    """Row i of the C-contiguous 2-D array ``a``, shape (a.shape[1],), borrowed."""
    return numba.carray(_item_pointer(a, i), a.shape[1])


@jit_inline
def matrix(a, i):
    """Matrix i of the C-contiguous 3-D array ``a``, shape (a.shape[1], a.shape[2]), borrowed."""
    return numba.carray(_item_pointer(a, i), (a.shape[1], a.shape[2]))


@jit_inline
def whole(a):
    """The whole C-contiguous array ``a``, borrowed (work space handed to inlined functions)."""
    return numba.carray(_item_pointer(a, 0), a.shape)


@intrinsic
def fixed(typingctx, a, rows, cols):
    """The C-contiguous 2-D array ``a`` as an array of shape (rows, cols), given as integer
    constants, with no owner: a loop over its columns then indexes its rows at constant strides,
    which LLVM's vectoriser needs to prove them apart. An intrinsic (no compiled function that
    returns an array), so that it serves code compiled without reference counting (_nrt=False)."""
    if not isinstance(a, types.Array) or a.ndim != 2 or a.layout != "C":
        raise TypingError(f"fixed() needs a C-contiguous 2-D array, got {a}")
    if not (isinstance(rows, types.IntegerLiteral) and isinstance(cols, types.IntegerLiteral)):
        raise TypingError(f"fixed() needs its shape as integer constants, got {rows}, {cols}")
    shape = (rows.literal_value, cols.literal_value)
    sig = a(a, rows, cols)

    def codegen(context, builder, signature, args):
        aryty = signature.args[0]
        src = context.make_array(aryty)(context, builder, args[0])
        out = context.make_array(aryty)(context, builder)
        itemsize = context.get_abi_sizeof(context.get_data_type(aryty.dtype))
        intp = context.get_value_type(types.intp)
        context.populate_array(
            out, data=src.data, shape=[ir.Constant(intp, n) for n in shape],
            strides=[ir.Constant(intp, shape[1] * itemsize), ir.Constant(intp, itemsize)],
            itemsize=ir.Constant(intp, itemsize), meminfo=None)
        return out._getvalue()

    return sig, codegen
