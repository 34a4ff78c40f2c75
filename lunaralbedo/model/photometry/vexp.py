r"""An exponential LLVM can vectorise, for the phase factor :math:`e^{-c_1\alpha}` of eq. 2 (the PhotometryTK manual).

``exp(x)`` inside numba: a float32 ``x`` gives :math:`e^x` in float32 arithmetic (below); a
float64 ``x`` gives ``math.exp(x)`` (libm, full float64 accuracy: the forward model).  glibc's
``expf`` is a call, which keeps a loop scalar; this one is plain arithmetic, so the loops over
observations that call :func:`lunar_lambert.point <lunaralbedo.model.photometry.lunar_lambert.point>`
run 8 observations per AVX2 instruction.

Method (float32, no fused multiply-add, IEEE round to nearest): :math:`x = k \ln 2 + r` with
:math:`k` the nearest integer to :math:`x/\ln 2` (rounded by adding :math:`1.5 \cdot 2^{23}`,
whose low mantissa bits then hold :math:`k`), :math:`r = x - k\ln 2` in two parts (Cody-Waite:
:math:`k \ln 2_{hi}` is exact), :math:`|r| \le 0.347`; :math:`e^r` by its Taylor polynomial
of degree :data:`DEGREE` (truncation below :math:`3 \cdot 10^{-8}` relative, a quarter of a
float32 ulp); :math:`2^k` as two powers of two built from their exponent bits (so results
down to the smallest subnormal are rounded once).  Within 1 float32 ulp of :math:`e^x` for
every float32 argument (``tests/test_vexp.py`` checks it over the phase factor's range and
beyond); ~10 % of the values differ by 1 ulp from the correctly rounded ones, where glibc's
``expf`` differs in ~0.06 %.  Arguments are clamped to [-110, 89] first (beyond, the float32
result is 0 or inf anyway); NaN stays NaN.  Deterministic: the same operations in a fixed
order, the same bits in a vector lane as in scalar code.
"""
from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic, overload

_f = np.float32
#: :math:`1/\ln 2`; :math:`\ln 2 = \ln 2_{hi} + \ln 2_{lo}` with :math:`\ln 2_{hi}` in 9 bits
#: (exact products with :math:`|k| < 2^{15}`); the rounding shifter :math:`1.5 \cdot 2^{23}`.
INV_LN2 = _f(1.4426950408889634)
LN2_HI = _f(0.693359375)
LN2_LO = _f(math.log(2.0) - 0.693359375)
SHIFTER = _f(12582912.0)
#: Clamp of the argument: :math:`e^{-110} < 10^{-47}` rounds to 0 and :math:`e^{89} > 3.5 \cdot 10^{38}` to inf.
LOW, HIGH = _f(-110.0), _f(89.0)
#: Degree of the Taylor polynomial of :math:`e^r`, and its coefficients :math:`1/n!` in float32.
DEGREE = 7
COEFFS = tuple(_f(1.0 / math.factorial(n)) for n in range(DEGREE + 1))
_SHIFTER_BITS = 0x4B400000  # the int32 bits of SHIFTER: bits(s) - this = k


def exp(x):
    """:math:`e^x` (Python: ``math.exp``; inside numba see the module docstring)."""
    return math.exp(x)


@intrinsic
def _bits(typingctx, x):
    """The int32 bits of a float32."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(32))
    return types.int32(types.float32), codegen


@intrinsic
def _from_bits(typingctx, i):
    """The float32 of int32 bits."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.FloatType())
    return types.float32(types.int32), codegen


def _exp32(x):
    """float32 :math:`e^x` (module docstring)."""
    y = LOW if x < LOW else x  # comparisons are false for NaN: it passes
    y = HIGH if y > HIGH else y
    s = y * INV_LN2 + SHIFTER
    k = s - SHIFTER  # the nearest integer to y / ln 2, as a float32
    r = (y - k * LN2_HI) - k * LN2_LO
    c = COEFFS
    p = c[7]
    p = p * r + c[6]
    p = p * r + c[5]
    p = p * r + c[4]
    p = p * r + c[3]
    p = p * r + c[2]
    p = p * r + c[1]
    p = p * r + c[0]
    ki = _bits(s) - np.int32(_SHIFTER_BITS)  # k, -159 <= k <= 129
    half = ki >> 1
    return (p * _from_bits((half + np.int32(127)) << 23)) * _from_bits((ki - half + np.int32(127)) << 23)


@overload(exp, jit_options={"cache": True})
def _exp_overload(x):
    if isinstance(x, types.Float) and x.bitwidth == 32:
        return _exp32
    if isinstance(x, types.Float):
        return lambda x: math.exp(x)
    return None
