"""Lens distortion of the Kaguya (SELENE LISM) and Clementine UVVIS cameras, as ISIS models them (pure math).

Focal-plane coordinates in millimetres; ``undistort`` maps the distorted (measured)
focal-plane point to the undistorted one that defines the look vector, ``distort``
inverts it by fixed-point iteration (the distortions are small).

* Kaguya MI (ISIS ``KaguyaMiCameraDistortionMap``, the JAXA IK ``SEL_MI_V01.TI``):
  ``ux = BORESIGHT_X + a0 + a1 y + a2 y^2 [+ a3 y^3] + x`` and
  ``uy = BORESIGHT_Y + b0 + b1 y + b2 y^2 [+ b3 y^3] + y`` with ``(a_k)`` =
  ``DISTORTION_COEF_X``, ``(b_k)`` = ``DISTORTION_COEF_Y`` and ``y`` the *signed*
  distance along the line (the IK's ``r = -(n - CENTER) * PIXEL_SIZE``); three
  coefficients for the VIS head (13 um pixels), four for NIR.
* Kaguya TC (ISIS ``KaguyaTcCameraDistortionMap``): ``ux = x + a(r)``, ``uy = y + b(r)``
  with ``r = sqrt(x^2 + y^2)`` and cubic polynomials ``a``, ``b``; the IK's boresight
  offsets are added when ``boresight`` is given (ale's ``kaguyalism`` model).
* Clementine UVVIS (ISIS ``ClementineUvvisDistortionMap``, IK ``PP``, ``OD_K``,
  ``DECENTER``): with ``(x, y) = d - PP`` and ``rr = x^2 + y^2``,
  ``u = d + (x, y) (k1 + k2 rr + k3 rr^2) + (p1 (rr + 2x^2) + 2 p2 x y, 2 p1 x y + p2 (rr + 2y^2))``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .optics import _Iterative


def _poly(c, t):
    out = np.zeros_like(t)
    for k in reversed(c):
        out = out * t + k
    return out


@dataclass
class KaguyaMiDistortion(_Iterative):
    """Kaguya MI: polynomials in the signed along-line coordinate ``y`` (mm), plus the boresight offset."""

    coef_x: tuple[float, ...]
    coef_y: tuple[float, ...]
    boresight: tuple[float, float] = (0.0, 0.0)

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return (self.boresight[0] + _poly(self.coef_x, y) + x, self.boresight[1] + _poly(self.coef_y, y) + y)


@dataclass
class KaguyaTcDistortion(_Iterative):
    """Kaguya TC: cubic polynomials in the radius ``r = sqrt(x^2 + y^2)`` (mm) added to ``(x, y)``."""

    coef_x: tuple[float, float, float, float]
    coef_y: tuple[float, float, float, float]
    boresight: tuple[float, float] = (0.0, 0.0)

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        r = np.hypot(x, y)
        return (x + _poly(self.coef_x, r) + self.boresight[0], y + _poly(self.coef_y, r) + self.boresight[1])


@dataclass
class ClementineUvvisDistortion(_Iterative):
    """Clementine UVVIS: radial ``(k1, k2, k3)`` in ``rr`` and decentering ``(p1, p2)`` about ``PP`` (mm)."""

    pp: tuple[float, float] = (0.0, 0.0)
    odk: tuple[float, float, float] = (0.0, 0.0, 0.0)
    decenter: tuple[float, float] = (0.0, 0.0)

    def undistort(self, dx, dy):
        dx = np.asarray(dx, dtype=np.float64)
        dy = np.asarray(dy, dtype=np.float64)
        x, y = dx - self.pp[0], dy - self.pp[1]
        rr = x * x + y * y
        k1, k2, k3 = self.odk
        dr = k1 + k2 * rr + k3 * rr * rr
        p1, p2 = self.decenter
        return (dx + x * dr + p1 * (rr + 2 * x * x) + 2 * p2 * x * y,
                dy + y * dr + 2 * p1 * x * y + p2 * (rr + 2 * y * y))
