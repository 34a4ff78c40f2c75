r"""Reflectance models (seed 000 section 7, eq. 2).

Lunar-Lambertian reflectance of image :math:`k` at pixel :math:`(i, j)`:

.. math::

    R = \left(e^{-c_1 \alpha} + c_2\right)
        \left[(1 - L(\alpha)) \cos i + 2 L(\alpha) \frac{\cos i}{\cos i + \cos e}\right]

with :math:`L(\alpha) = 1 + A\alpha + B\alpha^2 + C\alpha^3`, :math:`\alpha` in
**degrees** inside :math:`L` (A = -0.019, B = 0.000242, C = -0.00000146) and in
**radians** inside the phase factor :math:`e^{-c_1\alpha} + c_2`.

The geometric part (the bracket) does not depend on the phase coefficients, so
the solver stores it once per observation and multiplies by the phase factor.
All functions are pure NumPy and broadcast over arrays.
"""
from __future__ import annotations

import numpy as np

from ..constants import LUNAR_LAMBERT_A, LUNAR_LAMBERT_B, LUNAR_LAMBERT_C

LAMBERT = 1
LUNAR_LAMBERT = 2
MOSAIC = 0
HAPKE = 3  # normalised Hapke (model.photometry.hapke_solver), no fitted parameters


def lunar_lambert_weight(alpha_deg):
    r""":math:`L(\alpha) = 1 + A\alpha + B\alpha^2 + C\alpha^3`, alpha in degrees (eq. 2)."""
    a = np.asarray(alpha_deg, dtype=np.float64)
    return 1.0 + a * (LUNAR_LAMBERT_A + a * (LUNAR_LAMBERT_B + a * LUNAR_LAMBERT_C))


def lunar_lambert_geometric(cos_i, cos_e, alpha_rad):
    r"""The bracket of eq. 2: :math:`(1-L)\cos i + 2L\cos i/(\cos i + \cos e)`.

    Zero where :math:`\cos i \le 0` or :math:`\cos e \le 0` (unlit or unseen).
    """
    cos_i = np.asarray(cos_i, dtype=np.float64)
    cos_e = np.asarray(cos_e, dtype=np.float64)
    L = lunar_lambert_weight(np.degrees(alpha_rad))
    lit = (cos_i > 0) & (cos_e > 0)
    denom = np.where(lit, cos_i + cos_e, 1.0)
    r = (1.0 - L) * cos_i + 2.0 * L * cos_i / denom
    return np.where(lit, r, 0.0)


def phase_factor(alpha_rad, c1, c2):
    r"""Phase factor :math:`e^{-c_1\alpha} + c_2`, alpha in radians (eq. 2)."""
    return np.exp(-c1 * np.asarray(alpha_rad, dtype=np.float64)) + c2


def phase_factor_derivatives(alpha_rad, c1):
    r""":math:`(\partial P/\partial c_1, \partial P/\partial c_2) = (-\alpha e^{-c_1\alpha}, 1)` (for eq. 5)."""
    a = np.asarray(alpha_rad, dtype=np.float64)
    return -a * np.exp(-c1 * a), np.ones_like(a)


def reflectance(kind, cos_i, cos_e, alpha_rad, c1=1.4, c2=0.5, hapke=None):
    """Reflectance of kind 0 (mosaic: 1), 1 (Lambertian: cos i), 2 (Lunar-Lambertian, eq. 2) or 3 (``hapke``,
    a :class:`~lunaralbedo.model.photometry.hapke_solver.HapkeModel` with constant parameters, normalised)."""
    if kind == HAPKE:
        return hapke.normalised(cos_i, cos_e, alpha_rad)
    if kind == MOSAIC:
        return np.ones(np.shape(cos_i))
    if kind == LAMBERT:
        ci = np.asarray(cos_i, dtype=np.float64)
        return np.where(ci > 0, ci, 0.0)
    if kind == LUNAR_LAMBERT:
        return phase_factor(alpha_rad, c1, c2) * lunar_lambert_geometric(cos_i, cos_e, alpha_rad)
    raise ValueError(f"reflectance kind must be 0, 1, 2 or 3, got {kind!r}")
