r"""Natural logarithms LLVM can vectorise, for the single-image log albedo of the outlier test.

glibc's ``log`` is a call, which keeps a loop over observations scalar (8-11 ns an
observation on this project's machine); :func:`log` (float64) and :func:`logf` (float32) are
plain arithmetic on the bits of their argument (no branch, no table), so a loop that calls
them runs four (float64) or eight (float32) values per AVX2 instruction.

:func:`log`, fdlibm's method (``e_log.c``, Sun Microsystems 1993) without its branches:
:math:`x = 2^k (1 + f)` with :math:`\sqrt2/2 \le 1 + f < \sqrt2` (the exponent field and the
mantissa's leading bits; subnormal arguments are scaled by :math:`2^{54}` first),
:math:`s = f / (2 + f)`,

.. math:: \log(1 + f) = 2\,\mathrm{artanh}\, s = f - \tfrac12 f^2 + s\,(\tfrac12 f^2 + R(s^2)),

:math:`R(z) = L_1 z + \dots + L_7 z^7` fdlibm's minimax polynomial (error below
:math:`2^{-58.45}` on :math:`|s| \le 0.1716`), and :math:`k \ln 2` in two parts
(:math:`\ln 2_{hi}` has 32 trailing zero bits: :math:`k \ln 2_{hi}` is exact).  Within 1 ulp
of :math:`\log x` over the whole float64 range.

:func:`logf`, Cephes' ``logf`` (S. L. Moshier, 1984) without its branches: the same
reduction to :math:`1 + f`, then :math:`\log(1 + f) = f - \tfrac12 f^2 + f^3 P(f)` with
Cephes' polynomial :math:`P` of degree 8 (no division) and :math:`k \ln 2` in two parts.
Within 1 float32 ulp of :math:`\log x` over the whole float32 range.

Both: 0 gives -inf, +inf gives +inf, negative numbers and NaN give NaN (``tests/test_vlog.py``
checks them against a long double reference).  No fused multiply-add and no fast-math: the
same IEEE operations in a vector lane as in scalar code, so the same bits for any vector width.
"""
from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from .photometry.vexp import _bits as _bits32, _from_bits as _from_bits32

#: :math:`\ln 2 = \ln 2_{hi} + \ln 2_{lo}` (fdlibm's split).
LN2_HI = 6.93147180369123816490e-01
LN2_LO = 1.90821492927058770002e-10
#: fdlibm's coefficients :math:`L_1 \dots L_7` of :math:`R(z)`.
LG = (6.666666666666735130e-01, 3.999999999940941908e-01, 2.857142874366239149e-01, 2.222219843214978396e-01,
      1.818357216161805012e-01, 1.531383769920937332e-01, 1.479819860511658591e-01)
_TWO54 = 18014398509481984.0  # 2**54: a subnormal argument times this is normal
_TINY = 2.2250738585072014e-308  # the least normal float64
_MANT = 0x000FFFFFFFFFFFFF
_ONE = 0x3FF0000000000000
_SQRT2_ROUND = 0x95F6400000000  # added to the mantissa: carries into bit 52 when 1.m >= sqrt(2)
_BIT52 = 0x0010000000000000


@intrinsic
def _bits(typingctx, x):
    """The int64 bits of a float64."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.int64(types.float64), codegen


@intrinsic
def _from_bits(typingctx, i):
    """The float64 of int64 bits."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


@njit(cache=True, error_model="numpy")
def log(x):
    r""":math:`\log x` of a float64 (module docstring): within 1 ulp, branch-free, vectorisable."""
    sub = x < _TINY
    y = x * _TWO54 if sub else x
    b = _bits(y)
    k = (b >> 52) - (1023 + 54 if sub else 1023)
    m = b & _MANT
    i = (m + _SQRT2_ROUND) & _BIT52  # 1.m >= sqrt(2): halve it, one more power of two
    k += i >> 52
    f = _from_bits(m | (i ^ _ONE)) - 1.0  # sqrt(2)/2 <= 1 + f < sqrt(2)
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (LG[1] + w * (LG[3] + w * LG[5]))
    t2 = z * (LG[0] + w * (LG[2] + w * (LG[4] + w * LG[6])))
    r = t2 + t1
    hfsq = 0.5 * f * f
    dk = np.float64(k)
    out = dk * LN2_HI - ((hfsq - (s * (hfsq + r) + dk * LN2_LO)) - f)
    ok = (x > 0.0) & (x < np.inf)
    return out if ok else (-np.inf if x == 0.0 else (x if x == np.inf else np.nan))


_f = np.float32
#: Cephes' coefficients of :math:`P(f)`, highest degree first, and its split of :math:`\ln 2`.
PF = tuple(_f(c) for c in (7.0376836292e-2, -1.1514610310e-1, 1.1676998740e-1, -1.2420140846e-1, 1.4249322787e-1,
                           -1.6668057665e-1, 2.0000714765e-1, -2.4999993993e-1, 3.3333331174e-1))
LN2F_HI, LN2F_LO = _f(0.693359375), _f(-2.12194440e-4)
_TINYF, _TWO25F = _f(1.17549435e-38), _f(33554432.0)  # the least normal float32; 2**25


@njit(cache=True, error_model="numpy")
def logf(x):
    r""":math:`\log x` of a float32, in float32 (module docstring): within 1 float32 ulp, branch-free, vectorisable."""
    sub = x < _TINYF
    y = x * _TWO25F if sub else x
    b = _bits32(y)
    k = (b >> 23) - (np.int32(127 + 25) if sub else np.int32(127))
    m = b & np.int32(0x7FFFFF)
    i = (m + np.int32(0x4AFB0D)) & np.int32(0x800000)  # carries into bit 23 when 1.m >= sqrt(2): halve it
    k += i >> 23
    f = _from_bits32(m | (i ^ np.int32(0x3F800000))) - _f(1.0)  # sqrt(2)/2 <= 1 + f < sqrt(2)
    z = f * f
    p = PF[0]
    for c in PF[1:]:
        p = p * f + c
    fk = _f(k)
    r = (p * f * z + LN2F_LO * fk) - _f(0.5) * z
    out = (f + r) + LN2F_HI * fk
    ok = (x > 0) & (x < np.inf)
    return out if ok else (_f(-np.inf) if x == 0 else (x if x == np.inf else _f(np.nan)))
