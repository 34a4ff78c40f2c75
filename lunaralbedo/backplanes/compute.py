"""Backplanes of a camera on a shape (sphere or DEM): per image pixel angles and ground point.

Orchestration over pure pieces: the camera gives rays and pixel times, the shape
the intersection and normals, :mod:`.angles` the angles.  Arrays are float32
``(lines, samples)``, degrees, NaN off the body (or where the DEM has no value).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ..camera.intersect import ray_dem, ray_sphere
from ..constants import MOON_RADIUS_KM
from .angles import BAND_NAMES, angles, neighbour_normals, planetocentric


@dataclass
class Shape:
    """The surface rays stop on: the 1737.4 km sphere (``height_m`` None) or a DEM.

    ``height_m(lon_deg, lat_deg)`` gives metres above the sphere; ``name`` says what it is.
    """

    name: str = "sphere"
    height_m: Callable | None = None

    @property
    def is_sphere(self) -> bool:
        return self.height_m is None


def _sun_at(ephemeris, et):
    """Sun positions (km, body-fixed) at times ``et``, evaluated once per distinct time."""
    flat = np.ravel(et)
    uniq, inv = np.unique(flat, return_inverse=True)
    sun = np.asarray(ephemeris.sun(uniq), dtype=np.float64).reshape(-1, 3)
    return sun[inv].reshape(np.shape(et) + (3,))


def _ground(camera, shape: Shape, sample, line):
    """Surface points (km) seen at cube pixels: ray and sphere, or ray and DEM (NaN off the body)."""
    origins, dirs = camera.rays(sample, line)
    if shape.is_sphere:
        return ray_sphere(origins, dirs, MOON_RADIUS_KM)
    return ray_dem(origins, dirs, shape.height_m)


def pixel_geometry(camera, ephemeris, shape: Shape, sample, line) -> dict[str, np.ndarray]:
    """Backplanes (float64, degrees; keys = :data:`BAND_NAMES`) at cube pixels ``(sample, line)`` (1-based)."""
    sample = np.asarray(sample, dtype=np.float64)
    line = np.asarray(line, dtype=np.float64)
    origins, _ = camera.rays(sample, line)
    pts = _ground(camera, shape, sample, line)
    sun = _sun_at(ephemeris, camera.pixel_et(sample, line))
    radial = pts / np.linalg.norm(pts, axis=-1, keepdims=True)
    phase, emission, incidence = angles(pts, radial, sun, origins)
    if shape.is_sphere:
        local_e, local_i = emission, incidence
    else:
        half = 0.5 - 1e-9  # ISIS: nexttoward(line -+ 0.5, line), i.e. just inside the pixel
        top, bottom = _ground(camera, shape, sample, line - half), _ground(camera, shape, sample, line + half)
        left, right = _ground(camera, shape, sample - half, line), _ground(camera, shape, sample + half, line)
        normals = neighbour_normals(top, bottom, left, right, pts)
        _, local_e, local_i = angles(pts, normals, sun, origins)
    lat, lon = planetocentric(pts)
    values = (phase, emission, incidence, local_e, local_i, lat, lon)
    return dict(zip(BAND_NAMES, values))


def image_backplanes(camera, ephemeris, shape: Shape, block_lines: int = 256) -> dict[str, np.ndarray]:
    """Backplanes of every pixel of the camera's cube: float32 ``(lines, samples)`` per band name."""
    lines, samples = camera.lines, camera.samples
    out = {name: np.full((lines, samples), np.nan, dtype=np.float32) for name in BAND_NAMES}
    s = np.arange(1, samples + 1, dtype=np.float64)
    for l0 in range(0, lines, block_lines):
        l1 = min(lines, l0 + block_lines)
        ss, ll = np.meshgrid(s, np.arange(l0 + 1, l1 + 1, dtype=np.float64))
        geo = pixel_geometry(camera, ephemeris, shape, ss, ll)
        for name in BAND_NAMES:
            out[name][l0:l1] = geo[name]
    return out
