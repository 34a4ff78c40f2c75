"""Legacy surface points, normals and reflectance on a DEM tile, pure math.

Conventions (SOURCES.md and the legacy numerics):

* a DEM pixel is the point ``(R + h)(cos lat cos lon, cos lat sin lon, sin lat)``
  in metres (R = 1737400 m), lon/lat of the pixel centre;
* the normal at ``(x, y)`` is ``-normalize((p - p_left) x (p - p_up))``; pixels
  of the first row/column, or next to a nodata height, have none;
* Lunar-Lambertian reflectance (eq. 2, :mod:`lunaralbedo.model.photometry.lunar_lambert`)
  stored as float32 (as the legacy images were), zero where ``cos i < 0.3``; ``c1``,
  ``c2`` rounded to float32 as the legacy parser stored them;
* Sun and spacecraft positions are given in km and used in metres.
"""
from __future__ import annotations

import numpy as np

from ..constants import MIN_COS_INCIDENCE, MOON_RADIUS_M
from ..model.photometry import lunar_lambert
from .vwgeo import Geo

MOSAIC, LAMBERT, LUNAR_LAMBERT = 0, 1, 2  # REFLECTANCE_TYPE codes (see model.photometry)


def surface(dem: np.ndarray, geo: Geo, nodata: float) -> tuple[np.ndarray, np.ndarray]:
    """``(points (H, W, 3) in m, normals (H, W, 3))``; normals are NaN where undefined."""
    h, w = dem.shape
    lon = np.radians(geo.lon(np.arange(w)))[None, :]
    lat = np.radians(geo.lat(np.arange(h)))[:, None]
    r = MOON_RADIUS_M + dem.astype(np.float64)
    cl = np.cos(lat)
    p = np.stack([r * cl * np.cos(lon), r * cl * np.sin(lon), r * np.sin(lat) * np.ones_like(lon)], axis=-1)
    bad = dem == np.float32(nodata)
    normals = np.full(p.shape, np.nan)
    ok = ~(bad[1:, 1:] | bad[1:, :-1] | bad[:-1, 1:])
    dx = p[1:, 1:] - p[1:, :-1]
    dy = p[1:, 1:] - p[:-1, 1:]
    n = np.cross(dx, dy)
    n = -n / np.linalg.norm(n, axis=-1, keepdims=True)
    normals[1:, 1:] = np.where(ok[..., None], n, np.nan)
    return p, normals


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def reflectance(kind: int, points, normals, sun_km, sc_km, c1: float, c2: float) -> tuple[np.ndarray, np.ndarray]:
    """``(R float32, alpha float32 radians)`` per pixel; R = 0 where undefined or too oblique.

    ``kind`` 0 gives R = 1 everywhere (mosaic), 1 Lambertian ``cos i``, 2
    Lunar-Lambertian.  Computed in float64 and stored as float32 (the legacy
    reflectance images were float); ``c1``, ``c2`` are used as float32.  This
    combination reproduces 52 of the 53 gold exposures to all printed digits.
    """
    shape = points.shape[:-1]
    if kind == MOSAIC:
        return np.ones(shape, dtype=np.float32), np.zeros(shape, dtype=np.float32)
    have = np.all(np.isfinite(normals), axis=-1)
    nrm = np.where(have[..., None], normals, 0.0)
    s = _unit(np.asarray(sun_km, dtype=np.float64) * 1000.0 - points)
    mu0 = np.sum(s * nrm, axis=-1)
    if kind == LAMBERT:
        return np.where(have, mu0, 0.0).astype(np.float32), np.zeros(shape, dtype=np.float32)
    v = _unit(np.asarray(sc_km, dtype=np.float64) * 1000.0 - points)
    mu = np.maximum(np.sum(v * nrm, axis=-1), 0.0)
    alpha = np.arccos(np.clip(np.sum(s * v, axis=-1), -1.0, 1.0))
    L = lunar_lambert.weight(alpha * 180.0 / np.pi)  # the legacy degrees conversion
    den = mu0 + mu
    with np.errstate(divide="ignore", invalid="ignore"):
        r = lunar_lambert.bracket(mu0, mu, L) * lunar_lambert.phase_factor(alpha, float(np.float32(c1)), float(np.float32(c2)))
    lit = have & (mu0 >= MIN_COS_INCIDENCE) & (den != 0) & (r > 0)
    return np.where(lit, r, 0.0).astype(np.float32), np.where(lit, alpha, np.nan).astype(np.float32)
