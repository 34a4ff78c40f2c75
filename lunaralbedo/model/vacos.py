r"""An arc cosine LLVM can vectorise, for the phase angle :math:`\alpha = \arccos(\mathbf{l}\cdot\mathbf{v})`
of Nefian et al. (LPSC), eqs. 4-5 (float64).

glibc's ``acos`` is a call (~13 ns on this project's machine), which keeps the loops of the
prepare step's geometry scalar; this one is plain arithmetic (~2.4 ns per value in a
vectorised loop, 4 lanes of AVX2).

Method: with :math:`a = |x|`,

* :math:`a \le 1/2`: :math:`\arccos a = \pi/2 - \arcsin a`, :math:`\arcsin a = a + a\,u\,P(u)`, :math:`u = a^2`;
* :math:`a > 1/2`: :math:`\arccos a = 2 \arcsin s`, :math:`s = \sqrt{z}`, :math:`z = (1 - a)/2`
  (exact in float64), :math:`\arcsin s = s + s\,z\,P(z)`;
* :math:`x < 0`: :math:`\arccos x = \pi - \arccos a`;

so :math:`P(u) = (\arcsin\sqrt u - \sqrt u)/u^{3/2} = \sum_{k\ge1} c_k u^{k-1}`,
:math:`c_k = \binom{2k}{k} 4^{-k}/(2k+1)`, is only needed on :math:`[0, 1/4]`. :data:`COEFFS`
is the Chebyshev interpolant of degree 12 of that series on :math:`[0, 1/4]` (4000 nodes, the
series summed to 400 terms in extended precision; ``tools/acos_coefficients.py`` derives
them), written in powers of :math:`u`: relative error of :math:`P` below :math:`4\cdot10^{-16}`,
whose weight in the result is at most :math:`0.05`.  Within 1 float64 ulp of NumPy's
``arccos`` (``tests/test_vacos.py``); exact at -1, 0, 1.  Arguments beyond [-1, 1] must be
clipped by the caller.  Deterministic: the same operations in a fixed order (no fused
multiply-add), the same bits in a vector lane as in scalar code.
"""
from __future__ import annotations

import math

from numba import njit

#: :math:`P(u)` in powers of :math:`u` (module docstring; ``tools/acos_coefficients.py``).
COEFFS = (
    0.16666666666666666,
    0.07499999999998146,
    0.0446428571466724,
    0.03038194412349693,
    0.02237217333618461,
    0.017352386373250313,
    0.01397127846859868,
    0.011478746102892463,
    0.01032452311035239,
    0.005454256292716113,
    0.01739963425782503,
    -0.01483524103724531,
    0.02873696736708714,
)
_P0, _P1, _P2, _P3, _P4, _P5, _P6, _P7, _P8, _P9, _P10, _P11, _P12 = COEFFS
_HALF_PI = math.pi / 2.0
_PI = math.pi


@njit(cache=True, inline="always")
def _series(u):
    """:math:`P(u)` by Horner's rule."""
    return _P0 + u * (_P1 + u * (_P2 + u * (_P3 + u * (_P4 + u * (_P5 + u * (_P6 + u * (
        _P7 + u * (_P8 + u * (_P9 + u * (_P10 + u * (_P11 + u * _P12)))))))))))


@njit(cache=True, inline="always")
def acos(x):
    r""":math:`\arccos x` (radians, float64) for :math:`-1 \le x \le 1` (see the module docstring).

    Both branches are computed and one is selected, so a loop of calls has no branch to
    keep it scalar.
    """
    a = abs(x)
    far = a > 0.5
    z_far = 0.5 * (1.0 - a)
    z = z_far if far else a * a
    s = math.sqrt(z_far)
    s = s if far else a
    asin = s + s * z * _series(z)
    v = 2.0 * asin if far else _HALF_PI - asin
    return v if x >= 0.0 else _PI - v
