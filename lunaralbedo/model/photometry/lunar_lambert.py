r"""Lunar-Lambertian model (REFLECTANCE_TYPE 2; the PhotometryTK manual, section 7, eq. 2).

.. math::

    R = \left(e^{-c_1 \alpha} + c_2\right)
        \left[(1 - L(\alpha)) \cos i + 2 L(\alpha) \frac{\cos i}{\cos i + \cos e}\right]

with :math:`L(\alpha) = 1 + A\alpha + B\alpha^2 + C\alpha^3`, :math:`\alpha` in
**degrees** inside :math:`L` (A = -0.019, B = 0.000242, C = -0.00000146) and in
**radians** inside the phase factor :math:`P = e^{-c_1\alpha} + c_2`.  Fitted
parameters: :math:`c_1, c_2` (settings PHASE_COEFF_C1, PHASE_COEFF_C2).

The bracket (``geometric``) does not depend on :math:`c_1, c_2`, so the solver
caches it with :math:`\alpha` and multiplies by :math:`P` each iteration.  All
functions broadcast over arrays; the phase factor is one numba scalar function (:func:`point`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .base import PhotometricModel
from . import vexp
from .pointwise import evaluate

#: :math:`L(\alpha)` polynomial, alpha in degrees (eq. 2).
A, B, C = -0.019, 0.000242, -0.00000146


def _polynomial(a):
    """:math:`L` of eq. 2 for ``a`` in degrees: the one formula (NumPy below, numba in :func:`_geometric_over`)."""
    return 1.0 + a * (A + a * (B + a * C))


def weight(alpha_deg):
    r""":math:`L(\alpha) = 1 + A\alpha + B\alpha^2 + C\alpha^3`, alpha in degrees (eq. 2); keeps float32 input float32."""
    a = np.asarray(alpha_deg)
    if a.dtype != np.float32:
        a = a.astype(np.float64)
    return _polynomial(a)


def bracket(cos_i, cos_e, L):
    r"""The bracket of eq. 2, :math:`(1-L)\cos i + 2L\cos i/(\cos i + \cos e)`, as is (no masking)."""
    return (1.0 - L) * cos_i + 2.0 * L * cos_i / (cos_i + cos_e)


# IEEE division (error_model="numpy"): Python's zero-division check, compiled into each division, kept
# LLVM from vectorising _geometric_over's loop (2.1-4.2 -> 1.0 ns per element; its divisor is > 0 anyway).
# Set here, not only on the caller: an inlined function keeps the flags it was first compiled with.
_polynomial_nb = njit(cache=True, error_model="numpy")(_polynomial)
_bracket_nb = njit(cache=True, error_model="numpy")(bracket)
#: ``np.degrees``' factor (it multiplies by 180/pi, rounded once).
_DEGREES = 180.0 / math.pi


@njit(cache=True, nogil=True, error_model="numpy")
def _geometric_over(cos_i, cos_e, alpha_rad, out):
    """:func:`geometric` per element (float64): the same operations as the NumPy form, in one pass."""
    for o in range(out.shape[0]):
        ci, ce = cos_i[o], cos_e[o]
        out[o] = _bracket_nb(ci, ce, _polynomial_nb(alpha_rad[o] * _DEGREES)) if (ci > 0 and ce > 0) else 0.0


def geometric(cos_i, cos_e, alpha_rad, dtype=np.float64):
    r"""The bracket of eq. 2 with :math:`L(\alpha)`; zero where :math:`\cos i \le 0` or :math:`\cos e \le 0`.

    Computed in float64; ``dtype=np.float32`` stores each value rounded once (what the cache keeps), with
    no float64 array in between."""
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (cos_i, cos_e, alpha_rad)))
    out = np.empty(arrays[0].size, dtype)
    _geometric_over(*(np.ascontiguousarray(a).ravel() for a in arrays), out)
    return out.reshape(arrays[0].shape)


@njit(cache=True, nogil=True)
def point(g, alpha, _unused, c):
    r"""One observation (eq. 2): :math:`(R, \partial R/\partial c_1, \partial R/\partial c_2)
    = ((e^{-c_1\alpha} + c_2) G,\; -\alpha e^{-c_1\alpha} G,\; G)`, in the dtype of ``g``, ``alpha``, ``c``.

    The one implementation of the phase factor: the NumPy functions below run it over
    arrays (:func:`.pointwise.evaluate`) and the iterate kernel inlines it.
    """
    e = vexp.exp(-c[0] * alpha)
    return (e + c[1]) * g, -alpha * e * g, g


@njit(cache=True, nogil=True)
def _over_arrays(g, alpha, unused, c, out):
    """:func:`point` over arrays (:func:`.pointwise.evaluate`): rows R, dR/dc1, dR/dc2 of ``out``."""
    m = out.shape[0]
    for o in range(g.shape[0]):
        r, d1, d2 = point(g[o], alpha[o], unused[o], c)
        out[0, o] = r
        if m > 1:
            out[1, o] = d1
        if m > 2:
            out[2, o] = d2


def _phase(alpha, c1, c2, n_out):
    a = np.asarray(alpha)
    one = np.ones((), np.float32 if a.dtype == np.float32 else np.float64)
    return evaluate(_over_arrays, (one, a), (c1, c2), n_out)


def phase_factor(alpha_rad, c1, c2):
    r"""Phase factor :math:`P = e^{-c_1\alpha} + c_2`, alpha in radians (eq. 2); float32 stays float32."""
    return _phase(alpha_rad, c1, c2, 1)[0]


def layers(cos_i, cos_e, alpha, lon=None, lat=None):
    """Cached per observation: the bracket of eq. 2 (``geometric``, float32 as cached) and the phase angle (``alpha``,
    radians)."""
    return {"geometric": geometric(cos_i, cos_e, alpha, np.float32), "alpha": alpha}


def reflectance_from(arrays, params):
    """:math:`R = P(\\alpha)\\,G` from the cached layers (dtype of the layers)."""
    return evaluate(_over_arrays, (arrays["geometric"], arrays["alpha"]), params)[0]


def derivatives_from(arrays, params):
    r""":math:`(\partial R/\partial c_1, \partial R/\partial c_2) = (-\alpha e^{-c_1\alpha} G,\; G)`."""
    out = evaluate(_over_arrays, (arrays["geometric"], arrays["alpha"]), params, 3)
    return out[1], out[2]


def reflectance(cos_i, cos_e, alpha, params=(1.4, 0.5)):
    """Eq. 2 (float64: the bracket as computed, not rounded as the cache keeps it); 0 where unlit or unseen."""
    alpha = np.asarray(alpha, dtype=np.float64)
    return reflectance_from({"geometric": geometric(cos_i, cos_e, alpha), "alpha": alpha}, params)


MODEL = PhotometricModel(
    name="lunar-lambert",
    code=2,
    description="Lunar-Lambertian (McEwen), the PhotometryTK manual, eq. 2; fits c1, c2 of the phase factor",
    layers=layers,
    layer_names=("geometric", "alpha"),
    reflectance_from=reflectance_from,
    reflectance=reflectance,
    parameters=("c1", "c2"),
    derivatives_from=derivatives_from,
    point=point,
    point_layers=("geometric", "alpha"),
    point_kind=1,
    settings={"PHASE_COEFF_C1": (float, 1.4, None), "PHASE_COEFF_C2": (float, 0.5, None)},
    initial_keys=("PHASE_COEFF_C1", "PHASE_COEFF_C2"),
    curve=lambda alpha, params: phase_factor(alpha, params[0], params[1]),  # R / G: the phase factor
)
