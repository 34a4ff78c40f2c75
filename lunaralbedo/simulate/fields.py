"""Known Moons for the DRG strip: a textured albedo and a DEM of hills and craters, as pure functions of position.

Longitudes and latitudes in degrees, heights in metres above the 1737.4 km sphere.
Pure NumPy, no I/O: any window of a scene can be evaluated alone.
"""
from __future__ import annotations

import numpy as np

from ..constants import MOON_RADIUS_KM


def _features(extent, per_square_degree, seed):
    """Random blobs ``(cx, cy, r, sign)`` over ``extent`` (lon_min, lon_max, lat_min, lat_max), degrees."""
    rng = np.random.default_rng(seed)
    area = (extent[1] - extent[0]) * (extent[3] - extent[2])
    n = max(3, int(round(per_square_degree * area)))
    return [(rng.uniform(extent[0], extent[1]), rng.uniform(extent[2], extent[3]), rng.uniform(0.05, 0.2), rng.choice([-1.0, 1.0]))
            for _ in range(n)]


def _near(features, lon, lat, reach):
    """The features within ``reach`` radii of the window (the others add less than 1e-5 there)."""
    lo0, lo1, la0, la1 = np.min(lon), np.max(lon), np.min(lat), np.max(lat)
    return [f for f in features if lo0 - reach * f[2] <= f[0] <= lo1 + reach * f[2] and la0 - reach * f[2] <= f[1] <= la1 + reach * f[2]]


def truth_albedo(lon, lat, extent, seed=3):
    """A textured albedo field (dimensionless, 0.3..1.8) of lon/lat (degrees) over ``extent``.

    A pure function of position: any window of the scene can be evaluated alone.
    """
    rng = np.random.default_rng(seed)
    a = np.ones(np.broadcast(lon, lat).shape, dtype=np.float64)
    for _ in range(6):
        kx, ky = rng.uniform(2, 9, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        a += 0.06 * np.sin(kx * lon + ph[0]) * np.cos(ky * lat + ph[1])
    for cx, cy, r, sign in _near(_features(extent, 4.0, seed + 100), lon, lat, 5):  # bright ejecta / dark patches
        a += (0.3 if sign > 0 else -0.25) * np.exp(-((lon - cx) ** 2 + (lat - cy) ** 2) / (2 * r * r))
    return np.clip(a, 0.3, 1.8)


def truth_dem(lon, lat, extent, relief_m, seed=5, fresh_per_square_degree=0.0):
    """Heights (metres above the 1737.4 km sphere) with gentle hills and craters over ``extent``.

    With ``fresh_per_square_degree`` > 0, fresh bowl craters (:func:`fresh_craters`) are added.
    """
    h = relief_m * 0.3 * np.sin(2.5 * lon) * np.cos(3.1 * lat)
    for cx, cy, r, _ in _near(_features(extent, 2.5, seed), lon, lat, 3):
        d2 = ((lon - cx) ** 2 + (lat - cy) ** 2) / (r * r)
        h = h + relief_m * (-np.exp(-d2 * 2) + 0.4 * np.exp(-((np.sqrt(d2) - 1) ** 2) * 8))
    if fresh_per_square_degree > 0:
        h = h + fresh_craters(lon, lat, extent, fresh_per_square_degree, seed + 50)
    return h


def fresh_craters(lon, lat, extent, per_square_degree, seed=55):
    """Heights (metres) of fresh simple craters: parabolic bowls, depth 0.2 x diameter, raised rims.

    Radii 0.6-2.4 km (0.02-0.08 degrees); inside the rim (normalised radius
    :math:`\rho < 1`) :math:`h = d(\rho^2 - 1) + h_r`, outside :math:`h_r\rho^{-3}`, with
    depth :math:`d = 0.4 r` and rim height :math:`h_r = 0.08 r` (walls ~39 degrees at the rim), the
    outer flank brought smoothly to zero at 4 radii.
    """
    rng = np.random.default_rng(seed)
    area = (extent[1] - extent[0]) * (extent[3] - extent[2])
    n = max(1, int(round(per_square_degree * area)))
    cx = rng.uniform(extent[0], extent[1], n)
    cy = rng.uniform(extent[2], extent[3], n)
    rad = 0.02 * 4.0 ** rng.uniform(0, 1, n)
    h = np.zeros(np.broadcast(lon, lat).shape)
    lo0, lo1, la0, la1 = np.min(lon), np.max(lon), np.min(lat), np.max(lat)
    for x, y, r in zip(cx, cy, rad):
        if not (lo0 - 4 * r <= x <= lo1 + 4 * r and la0 - 4 * r <= y <= la1 + 4 * r):
            continue
        rho = np.sqrt((lon - x) ** 2 + (lat - y) ** 2) / r
        r_m = np.radians(r) * MOON_RADIUS_KM * 1000.0
        depth, rim = 0.4 * r_m, 0.08 * r_m
        outside = rim * np.clip((np.maximum(rho, 1) ** -3 - 1 / 64) / (1 - 1 / 64), 0, None)  # zero from 4 radii
        h += np.where(rho < 1, depth * (rho**2 - 1) + rim, outside)
    return h
