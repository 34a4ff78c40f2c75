r"""A natural logarithm LLVM can vectorise, for the single-image log albedo of the outlier test.

glibc's ``log`` is a call, which keeps a loop over observations scalar (8-11 ns an
observation on this project's machine); :func:`logf` (float32) is plain arithmetic on the
bits of its argument (no branch, no table), so a loop that calls it runs eight values per
AVX2 instruction.

:func:`logf`, Cephes' ``logf`` (S. L. Moshier, 1984) without its branches:
:math:`x = 2^k (1 + f)` with :math:`\sqrt2/2 \le 1 + f < \sqrt2` (the exponent field and the
mantissa's leading bits; subnormal arguments are scaled by :math:`2^{25}` first), then
:math:`\log(1 + f) = f - \tfrac12 f^2 + f^3 P(f)` with Cephes' polynomial :math:`P` of degree 8
(no division) and :math:`k \ln 2` in two parts.  Within 1 float32 ulp of :math:`\log x` over
the whole float32 range.  0 gives -inf, +inf gives +inf, negative numbers and NaN give NaN
(``tests/test_vlog.py`` checks them against a long double reference).  No fused multiply-add
and no fast-math: the same IEEE operations in a vector lane as in scalar code, so the same
bits for any vector width.  (A float64 twin, fdlibm's method, was written and tested too; the
outlier test needs only float32, so it is not kept.)
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .photometry.vexp import _bits as _bits32, _from_bits as _from_bits32

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
