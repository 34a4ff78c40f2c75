"""Focal plane <-> detector transforms and lens distortion, as ISIS defines them in IKs (pure math).

Units: focal-plane coordinates in millimetres, detector coordinates in pixels.
ISIS conventions kept here:

* detector offsets are relative to the detector origin (``BORESIGHT_SAMPLE/LINE``
  or ``CCD_CENTER``); ``x = TRANSX[0] + TRANSX[1]*ds + TRANSX[2]*dl`` and likewise
  ``y``; the inverse uses ``ITRANSS`` / ``ITRANSL``;
* the look vector in the instrument frame is ``(ux, uy, zdir * FOCAL_LENGTH)`` for
  the undistorted focal-plane point ``(ux, uy)``; ``zdir`` is +1 except for the
  Apollo Metric camera, whose ISIS distortion map looks along -Z (its CK, checked
  against ALE's ISD for AS15-M-1450, has +Z pointing away from the Moon).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class NoDistortion:
    """Identity distortion."""

    def undistort(self, x, y):
        return np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)

    def distort(self, ux, uy):
        return np.asarray(ux, dtype=np.float64), np.asarray(uy, dtype=np.float64)


class _Iterative:
    """Inverse of :meth:`undistort` by fixed-point iteration (distortions here are small)."""

    def distort(self, ux, uy, iterations: int = 20):
        ux = np.asarray(ux, dtype=np.float64)
        uy = np.asarray(uy, dtype=np.float64)
        x, y = ux.copy(), uy.copy()
        for _ in range(iterations):
            gx, gy = self.undistort(x, y)
            x, y = x + (ux - gx), y + (uy - gy)
        return x, y


@dataclass
class RadialOdk(_Iterative):
    """ISIS default map: ``u = d - d * (k0 + k1 r^2 + k2 r^4)`` with ``OD_K = (k0, k1, k2)``."""

    odk: tuple[float, ...] = (0.0, 0.0, 0.0)

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        k = list(self.odk) + [0.0] * (3 - len(self.odk))
        r2 = x * x + y * y
        d = k[0] + r2 * (k[1] + r2 * k[2])
        return x - d * x, y - d * y


@dataclass
class LroNacDistortion(_Iterative):
    """LRO NAC (single ``OD_K``): ``u = d / (1 + k r^2)``."""

    k: float = 0.0

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        den = 1.0 + self.k * (x * x + y * y)
        return x / den, y / den


@dataclass
class ApolloMetricDistortion(_Iterative):
    """Apollo Metric (IAK): principal point ``PP``, radial ``OD_K`` (r^2, r^4, r^6), decentering ``(j1, j2, t0)``."""

    pp: tuple[float, float] = (0.0, 0.0)
    odk: tuple[float, float, float] = (0.0, 0.0, 0.0)
    decenter: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def undistort(self, x, y):
        x = np.asarray(x, dtype=np.float64) - self.pp[0]
        y = np.asarray(y, dtype=np.float64) - self.pp[1]
        k1, k2, k3 = self.odk
        j1, j2, t0 = self.decenter
        r2 = x * x + y * y
        dr = r2 * (k1 + r2 * (k2 + r2 * k3))
        p1, p2 = -j1 * np.sin(np.radians(t0)), j1 * np.cos(np.radians(t0))
        tx = (1 + j2 * r2) * (p1 * (r2 + 2 * x * x) + 2 * p2 * x * y)
        ty = (1 + j2 * r2) * (2 * p1 * x * y + p2 * (r2 + 2 * y * y))
        return x - x * dr - tx, y - y * dr - ty


@dataclass
class FocalPlane:
    """IK focal-plane geometry of one instrument (millimetres, pixels)."""

    focal_length: float
    transx: tuple[float, float, float]
    transy: tuple[float, float, float]
    itranss: tuple[float, float, float]
    itransl: tuple[float, float, float]
    origin_sample: float
    origin_line: float
    distortion: object = field(default_factory=NoDistortion)
    z_direction: float = 1.0

    def detector_to_focal(self, ds, dl):
        """Detector offsets (pixels from the origin) to distorted focal-plane mm."""
        tx, ty = self.transx, self.transy
        return tx[0] + tx[1] * ds + tx[2] * dl, ty[0] + ty[1] * ds + ty[2] * dl

    def focal_to_detector(self, x, y):
        """Distorted focal-plane mm to detector offsets (pixels from the origin)."""
        s, l = self.itranss, self.itransl
        return s[0] + s[1] * x + s[2] * y, l[0] + l[1] * x + l[2] * y

    def look(self, ds, dl) -> np.ndarray:
        """Unit look vectors ``(..., 3)`` in the instrument frame for detector offsets."""
        ux, uy = self.distortion.undistort(*self.detector_to_focal(np.asarray(ds, float), np.asarray(dl, float)))
        v = np.stack([ux, uy, np.full(np.shape(ux), self.z_direction * self.focal_length)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def project(self, v):
        """Detector offsets ``(ds, dl)`` of instrument-frame vectors ``(..., 3)``; NaN behind the camera."""
        v = np.asarray(v, dtype=np.float64)
        z = v[..., 2] * self.z_direction
        with np.errstate(invalid="ignore", divide="ignore"):
            ux = np.where(z > 0, self.focal_length * v[..., 0] / z, np.nan)
            uy = np.where(z > 0, self.focal_length * v[..., 1] / z, np.nan)
        return self.focal_to_detector(*self.distortion.distort(ux, uy))
