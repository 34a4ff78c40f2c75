r"""Photometric angles and ground coordinates of image pixels (pure NumPy; body-fixed km, degrees).

For a ground point :math:`\mathbf p`, unit vectors to the Sun :math:`\hat l` and to the
spacecraft :math:`\hat v`, and a unit normal :math:`\hat n`:
phase :math:`g = \arccos(\hat l\cdot\hat v)`, incidence :math:`i = \arccos(\hat n\cdot\hat l)`,
emission :math:`e = \arccos(\hat n\cdot\hat v)` (Nefian et al. (LPSC), eqs. 4-5).  As ISIS does, the
plain "Incidence/Emission Angle" use the normal of the reference sphere (radial) and the
"Local" ones the normal of the DEM surface.

Local normals follow ISIS ``Camera::GetLocalNormal``: the DEM surface points seen half a
pixel above, below, left and right of the pixel, normal = (top - bottom) x (right - left),
pointing outward.
"""
from __future__ import annotations

import numpy as np

from ..model.geometry import lonlat_height

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


def neighbour_normals(top, bottom, left, right, center):
    """Outward unit normals (top - bottom) x (right - left) of surface points (ISIS ``DemShape``), ``(..., 3)`` km."""
    n = _unit(np.cross(top - bottom, right - left))
    outward = np.einsum("...i,...i->...", n, center) >= 0
    return np.where(outward[..., None], n, -n)


def planetocentric(points_km):
    """Latitude (planetocentric) and longitude (0-360 east), degrees, of body-fixed points."""
    lon, lat, _ = lonlat_height(points_km)
    return lat, np.mod(lon, 360.0)
