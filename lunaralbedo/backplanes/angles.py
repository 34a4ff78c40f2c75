r"""Photometric angles and ground coordinates of image pixels (pure NumPy; body-fixed km, degrees).

For a ground point :math:`\mathbf p`, unit vectors to the Sun :math:`\hat l` and to the
spacecraft :math:`\hat v`, and a unit normal :math:`\hat n`:
phase :math:`g = \arccos(\hat l\cdot\hat v)`, incidence :math:`i = \arccos(\hat n\cdot\hat l)`,
emission :math:`e = \arccos(\hat n\cdot\hat v)` (seed 001 eqs. 4-5).  As ISIS does, the
plain "Incidence/Emission Angle" use the normal of the reference sphere (radial) and the
"Local" ones the normal of the DEM surface.

DEM normals follow ISIS ``DemShape``: the four surface points one DEM pixel east, west,
north and south of the intersection, normal = (east - west) x (north - south), outward.
"""
from __future__ import annotations

import numpy as np

from ..model.geometry import body_fixed, lonlat_height

#: Band descriptions of the backplanes, exactly as ISIS phocube writes them.
BAND_NAMES = ("Phase Angle", "Emission Angle", "Incidence Angle", "Local Emission Angle",
              "Local Incidence Angle", "Latitude", "Longitude")


def _unit(v):
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _angle(a, b):
    """Angle (degrees) between unit vectors ``(..., 3)``."""
    return np.degrees(np.arccos(np.clip(np.einsum("...i,...i->...", a, b), -1.0, 1.0)))


def angles(points_km, normals, sun_km, spacecraft_km):
    """``(phase, emission, incidence)`` in degrees for points with unit ``normals``."""
    l = _unit(np.asarray(sun_km, dtype=np.float64) - points_km)
    v = _unit(np.asarray(spacecraft_km, dtype=np.float64) - points_km)
    return _angle(l, v), _angle(normals, v), _angle(normals, l)


def dem_local_normals(points_km, height_m, step_deg: float):
    """ISIS ``DemShape`` local normals at ``points_km`` from ``height_m(lon, lat)`` sampled ``step_deg`` away."""
    lon, lat, _ = lonlat_height(points_km)
    d = float(step_deg)

    def at(dlon, dlat):
        lo, la = lon + dlon, lat + dlat
        return body_fixed(lo, la, height_m(lo, la))

    east, west, north, south = at(d, 0.0), at(-d, 0.0), at(0.0, d), at(0.0, -d)
    n = _unit(np.cross(east - west, north - south))
    outward = np.einsum("...i,...i->...", n, points_km) >= 0
    return np.where(outward[..., None], n, -n)


def planetocentric(points_km):
    """Latitude (planetocentric) and longitude (0-360 east), degrees, of body-fixed points."""
    lon, lat, _ = lonlat_height(points_km)
    return lat, np.mod(lon, 360.0)
