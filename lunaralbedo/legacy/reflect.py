"""Legacy surface points, normals and reflectance on a DEM tile, pure math.

Conventions (SOURCES.md and the legacy numerics):

* a DEM pixel is the point ``(R + h)(cos lat cos lon, cos lat sin lon, sin lat)``
  in metres (R = 1737400 m), lon/lat of the pixel centre (``model.geometry.body_fixed``);
* the normal at ``(x, y)`` is ``-normalize((p - p_left) x (p - p_up))`` (``model.geometry.dem_normals``
  with backward differences); pixels of the first row/column, or next to a nodata height, have none;
* Lunar-Lambertian reflectance (eq. 2, :mod:`lunaralbedo.model.photometry.lunar_lambert`)
  stored as float32 (as the legacy images were), zero where ``cos i < 0.3``; ``c1``,
  ``c2`` rounded to float32 as the legacy parser stored them;
* illumination angles (cos i, cos e, phase) are :func:`lunaralbedo.model.geometry.illumination`
  (its sums run left to right, the legacy order);
* Sun and spacecraft positions are given in km and used in metres.
"""
from __future__ import annotations

import numpy as np

from ..constants import MIN_COS_INCIDENCE
from ..model import geometry
from ..model.photometry import lunar_lambert
from .vwgeo import Geo

MOSAIC, LAMBERT, LUNAR_LAMBERT = 0, 1, 2  # REFLECTANCE_TYPE codes (see model.photometry)


def surface(dem: np.ndarray, geo: Geo, nodata: float) -> tuple[np.ndarray, np.ndarray]:
    """``(points (H, W, 3) in m, normals (H, W, 3))``; normals are NaN where undefined.

    Points and normals are :func:`lunaralbedo.model.geometry.body_fixed` (in metres)
    and :func:`~lunaralbedo.model.geometry.dem_normals` with backward differences.
    """
    h, w = dem.shape
    lon = np.broadcast_to(geo.lon(np.arange(w))[None, :], (h, w))
    lat = np.broadcast_to(geo.lat(np.arange(h))[:, None], (h, w))
    p = geometry.body_fixed(lon, lat, dem, unit="m")
    bad = (dem == np.float32(nodata))[..., None]
    return p, geometry.dem_normals(np.where(bad, np.nan, p), differences="backward")


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
    sun_m, sc_m = (np.asarray(p, dtype=np.float64) * 1000.0 for p in (sun_km, sc_km))
    mu0, mu, alpha = geometry.illumination(points, nrm, sun_m, sc_m)
    if kind == LAMBERT:
        return np.where(have, mu0, 0.0).astype(np.float32), np.zeros(shape, dtype=np.float32)
    mu = np.maximum(mu, 0.0)
    L = lunar_lambert.weight(alpha * 180.0 / np.pi)  # the legacy degrees conversion
    den = mu0 + mu
    with np.errstate(divide="ignore", invalid="ignore"):
        r = lunar_lambert.bracket(mu0, mu, L) * lunar_lambert.phase_factor(alpha, float(np.float32(c1)), float(np.float32(c2)))
    lit = have & (mu0 >= MIN_COS_INCIDENCE) & (den != 0) & (r > 0)
    return np.where(lit, r, 0.0).astype(np.float32), np.where(lit, alpha, np.nan).astype(np.float32)
