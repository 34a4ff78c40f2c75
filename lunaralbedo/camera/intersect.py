"""Rays onto the Moon: sphere and DEM intersections (pure NumPy; body-fixed km)."""
from __future__ import annotations

import numpy as np

from ..constants import MOON_RADIUS_KM
from ..model.geometry import lonlat_height


def ray_sphere(origins, dirs, radius_km):
    """Nearest intersection of rays with a centred sphere (km); NaN where the ray misses."""
    o = np.asarray(origins, dtype=np.float64)
    d = np.asarray(dirs, dtype=np.float64)
    b = np.sum(o * d, axis=-1)
    c = np.sum(o * o, axis=-1) - np.asarray(radius_km, dtype=np.float64) ** 2
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    t = np.where((disc >= 0) & (t > 0), t, np.nan)
    return o + d * t[..., None]


def ray_dem(origins, dirs, height_m, iterations: int = 20, tol_m: float = 0.01):
    """Intersection of rays with a DEM given as ``height_m(lon_deg, lat_deg) -> metres``.

    Fixed-point iteration on the radius (converges for views not too oblique to
    gentle slopes); NaN where the ray misses or the DEM has no value.
    """
    h = np.zeros(np.shape(origins)[:-1])
    p = ray_sphere(origins, dirs, MOON_RADIUS_KM)
    for _ in range(iterations):
        lon, lat, _ = lonlat_height(p)
        h_new = np.asarray(height_m(lon, lat), dtype=np.float64)
        p = ray_sphere(origins, dirs, MOON_RADIUS_KM + h_new / 1000.0)
        if np.nanmax(np.abs(h_new - h), initial=0.0) < tol_m:
            break
        h = h_new
    return p
