"""Scalar building blocks that vectorise across lanes: a branch-free select, an exponential and
a division that single precision may do by the reciprocal.

The model's kernel advances many runs ("lanes") in one inner loop, which LLVM's loop vectoriser
turns into SIMD code when the loop body is straight-line arithmetic. Two things stop it:

* a branch in the body. :func:`where` is LLVM's ``select`` on scalars: both values are
  computed and one is kept, lane by lane, with no branch to convert;
* a math call without a vector form. numba lowers ``np.exp`` to ``llvm.exp``, which LLVM
  vectorises only through a vector math library (SVML, glibc's libmvec) named to its target
  library info; the llvmlite wheels offer neither (no SVML-patched LLVM, and LLVM 20+ takes the
  vector library from the frontend, which llvmlite does not expose), so the vector ``llvm.exp``
  is split back into one libm call per lane, at about the cost of the rest of the step.
  :func:`exp` is the exponential written in arithmetic the vectoriser handles: in float64 glibc's
  own algorithm (a table of 2**(i/128), a polynomial, fused multiply-adds in glibc's order), so
  that the results are libm's to the last bit; in float32 Cody and Waite's reduction and a
  polynomial. The power of two is assembled in the exponent bits.

Both are generic over float64 and float32 (the GSA's optional single-precision kernel).
"""

from __future__ import annotations

import math
import struct
from decimal import Decimal, getcontext

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import intrinsic, overload

jit_inline = numba.njit(cache=True, inline="always", error_model="numpy")


@intrinsic
def where(typingctx, cond, a, b):
    """``a`` where ``cond`` else ``b`` (scalars of one type): LLVM's ``select``, no branch."""
    if not isinstance(cond, types.Boolean) or a != b:
        raise TypingError(f"where(cond, a, b) needs a boolean and two values of one type, got {cond}, {a}, {b}")
    sig = a(cond, a, b)

    def codegen(context, builder, signature, args):
        return builder.select(args[0], args[1], args[2])

    return sig, codegen


@intrinsic
def sqrt(typingctx, x):
    """The square root of a float64 or float32 scalar as LLVM's ``llvm.sqrt`` (NaN below 0, as
    IEEE has it), which the vectoriser turns into one SIMD instruction. numba's ``np.sqrt`` is
    libm's ``sqrt``, which may set errno for a negative argument: LLVM keeps such a call scalar
    unless it can prove the argument non-negative."""
    if x not in (types.float64, types.float32):
        raise TypingError(f"sam.simd.sqrt takes float64 or float32, got {x}")
    sig = x(x)

    def codegen(context, builder, signature, args):
        fnty = ir.FunctionType(args[0].type, [args[0].type])
        name = "llvm.sqrt.f64" if signature.return_type == types.float64 else "llvm.sqrt.f32"
        return builder.call(cgutils.get_or_insert_function(builder.module, fnty, name), args)

    return sig, codegen


def quot(a, b):
    """a / b. Between float64 scalars (and arrays) an IEEE division, bit for bit. Between float32
    scalars (the GSA's single-precision kernel) the division may be done as a product with the
    reciprocal, which LLVM shares between divisions by one value and computes by the SIMD
    reciprocal estimate and a Newton step: within 2 float32 ulp of the quotient (a division's is
    0.5), at a fraction of a division's cost, the step's dearest instruction."""
    raise NotImplementedError("sam.simd.quot runs compiled (numba)")


@intrinsic
def _quot_arcp(typingctx, a, b):
    """a / b of two float32 with LLVM's fast-math flags arcp (the reciprocal may be used) and ninf
    (promising finite operands, which the reciprocal estimate needs). An infinite dividend or a zero
    divisor then gives NaN or inf, and an infinite divisor 0 or NaN (which one depends on whether the
    vector body or the scalar remainder of a loop computed it): only a run that has already gone
    non-finite meets one, and the GSA's NaN/inf check catches it either way."""
    if not a == b == types.float32:
        raise TypingError(f"_quot_arcp takes two float32, got {a}, {b}")

    def codegen(context, builder, signature, args):
        return builder.fdiv(args[0], args[1], flags=("arcp", "ninf"))

    return a(a, b), codegen


@overload(quot, jit_options={"cache": True, "inline": "always", "error_model": "numpy"})
def _quot(a, b):
    if a == b == types.float32:
        return lambda a, b: _quot_arcp(a, b)
    return lambda a, b: a / b


def exp(x):
    """e**x of a float64 or float32 scalar, vectorisable. float64: glibc's exp (2.28 and later, on
    x86-64 with FMA) to the last bit, so that the lane kernel computes what the scalar one did;
    float32: within 2 ulp. 0 below underflow, inf above overflow, NaN kept. An array (a numpy
    caller of a model function) goes to np.exp."""
    raise NotImplementedError("sam.simd.exp runs compiled (numba)")


@intrinsic
def fma(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's ``llvm.fma``, one vector instruction on x86-64 with FMA)."""
    if not (a == b == c) or a not in (types.float64, types.float32):
        raise TypingError(f"sam.simd.fma takes three float64 or three float32, got {a}, {b}, {c}")
    sig = a(a, b, c)

    def codegen(context, builder, signature, args):
        ty = args[0].type
        name = "llvm.fma.f64" if signature.return_type == types.float64 else "llvm.fma.f32"
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ty, [ty, ty, ty]), name)
        return builder.call(fn, args)

    return sig, codegen


def _exp_table(bits: int = 7) -> np.ndarray:
    """The 2 * 2**bits words of the table of e**x below: for k < 2**bits, the relative error of
    T_k = 2**(k / 2**bits) rounded to a double, as a double's bits, then T_k's bits less k << 45
    (the integer part of x / ln 2 is added to the exponent field later)."""
    getcontext().prec = 60
    words = []
    for k in range(1 << bits):
        exact = Decimal(2) ** (Decimal(k) / (1 << bits))
        T = float(exact)
        words += [_bits(float((exact - Decimal(T)) / Decimal(T))), _bits(T) - (k << (52 - bits))]
    return np.array(words, dtype=np.uint64)


def _bits(x: float) -> int:
    return struct.unpack("<Q", struct.pack("<d", x))[0]


# glibc's exp (Szabolcs Nagy's, 2018: from ARM's optimized-routines): x = (k + i/128) ln 2 + r,
# e**x = 2**k T_i (1 + tail_i) e**r, e**r - 1 by a degree-5 polynomial; its constants, so that the
# results are libm's to the last bit wherever the scalar kernel called libm.
_EXP_TAB = _exp_table()
_INV_LN2_N = float.fromhex("0x1.71547652b82fep0") * 128
_NEG_LN2_HI_N, _NEG_LN2_LO_N = float.fromhex("-0x1.62e42fefa0000p-8"), float.fromhex("-0x1.cf79abc9e3b3ap-47")
_SHIFT = float.fromhex("0x1.8p52")
_TWO_1009, _TWO_M1022 = 2.0**1009, 2.0**-1022
_C2, _C3, _C4, _C5 = (float.fromhex(c) for c in (
    "0x1.ffffffffffdbdp-2", "0x1.555555555543cp-3", "0x1.55555cf172b91p-5", "0x1.1111167a4d017p-7"))

# float32: Cody and Waite's reduction, ln 2 in two parts, the first with trailing zero bits so that
# n * LN2_HI is exact for every n the reduction produces; Taylor coefficients 1/k! of e**r for
# |r| <= ln(2)/2 to degree 7 (5e-9: below half a float32 ulp).
_LN2_HI_32, _LN2_LO_32 = np.float32(0.693145751953125), np.float32(1.428606765330187045e-06)
_TAYLOR_32 = tuple(np.float32(1.0 / math.factorial(k)) for k in range(7, -1, -1))


@overload(exp, jit_options={"cache": True, "inline": "always", "error_model": "numpy"})
def _exp(x):
    if x == types.float64:
        return _exp64
    if x == types.float32:
        return _exp32
    if isinstance(x, types.Array):
        return lambda x: np.exp(x)
    raise TypingError(f"sam.simd.exp takes float64 or float32, got {x}")


def _exp64(x):
    # every case is computed and one kept (a branch would stop the vectoriser); the order of the
    # fused multiply-adds is glibc's as GCC contracts it for its FMA variant
    abstop = (np.float64(x).view(np.uint64) >> np.uint64(52)) & np.uint64(0x7FF)
    kd = fma(_INV_LN2_N, x, _SHIFT)
    ki = np.float64(kd).view(np.uint64)
    kd = kd - _SHIFT
    r = fma(kd, _NEG_LN2_LO_N, fma(kd, _NEG_LN2_HI_N, x))
    i = (ki & np.uint64(127)) << np.uint64(1)
    tail = np.uint64(_EXP_TAB[i]).view(np.float64)
    sbits = _EXP_TAB[i + np.uint64(1)] + (ki << np.uint64(45))
    r2 = r * r
    tmp = fma(r2 * r2, fma(r, _C5, _C4), fma(r2, fma(r, _C3, _C2), tail + r))
    scale = np.uint64(sbits).view(np.float64)
    y = fma(scale, tmp, scale)
    # 512 <= |x| < 1024: 2**k overflows its exponent field; scaled apart, rounded once in the
    # subnormal range (glibc's specialcase)
    up = np.uint64(sbits - np.uint64(1009 << 52)).view(np.float64)
    y_up = _TWO_1009 * fma(up, tmp, up)
    down = np.uint64(sbits + np.uint64(1022 << 52)).view(np.float64)
    s_tmp = down * tmp  # two uses: GCC does not fuse it
    y_dn = down + s_tmp
    hi = 1.0 + y_dn
    lo = 1.0 - hi + y_dn + (down - y_dn + s_tmp)
    y_dn = _TWO_M1022 * where(y_dn < 1.0, (hi + lo) - 1.0, y_dn)
    y = where(abstop >= np.uint64(0x408), where((ki & np.uint64(0x80000000)) == np.uint64(0), y_up, y_dn), y)
    # |x| >= 1024: 0, inf or NaN; |x| < 2**-54: 1 + x
    huge = where(x < 0.0, 0.0, where(x != x, x, math.inf))
    return where(abstop >= np.uint64(0x409), huge, where(abstop < np.uint64(0x3C9), 1.0 + x, y))


def _exp32(x):
    xc = where(x > np.float32(-150.0), where(x < np.float32(89.0), x, np.float32(89.0)), np.float32(-150.0))
    n = np.floor(xc * np.float32(1.442695) + np.float32(0.5))
    r = (xc - n * _LN2_HI_32) - n * _LN2_LO_32
    p = np.float32(0.0)
    for c in _TAYLOR_32:
        p = p * r + c
    k = np.int32(n)
    k1 = k >> np.int32(1)
    s1 = np.int32((k1 + np.int32(127)) << np.int32(23)).view(np.float32)
    s2 = np.int32((k - k1 + np.int32(127)) << np.int32(23)).view(np.float32)
    return where(x != x, x, p * s1 * s2)


def float_type(a):
    """The scalar type (np.float64 or np.float32) of the float array ``a``: the ``f`` that the
    model functions write their constants in, ``f(0.5)``, so that float32 arithmetic stays float32."""
    raise NotImplementedError("sam.simd.float_type runs compiled (numba)")


@overload(float_type, jit_options={"cache": True, "inline": "always"})
def _float_type(a):
    if a.dtype == types.float32:
        return lambda a: np.float32
    if a.dtype == types.float64:
        return lambda a: np.float64
    raise TypingError(f"the model runs in float64 or float32, got {a.dtype}")
