"""Fused per-pixel pass of orthoprojection: DEM normal, visibility and bilinear sample (numba).

For output pixel ``(i, j)`` of a north-up grid: the body-fixed point of its DEM height
(km, 1737.4 km sphere), the outward normal from the neighbouring points (central
differences, one-sided at the grid's edges; the same formula as
:func:`lunaralbedo.model.geometry.dem_normals`; the radial direction on a grid one pixel
high or wide, which has no slope across it), ``cos e`` towards the spacecraft, and
the cube value at 1-based ``(sample, line)`` sampled bilinearly as
:func:`lunaralbedo.model.grid.bilinear_at` does.  NaN where the DEM has no value, the
point is not imaged or the slope faces away from the spacecraft (``cos e <= 0``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..constants import MOON_RADIUS_KM
from ..model.grid import bilinear_at


@njit(cache=True)
def _point(lon_deg, lat_deg, h_m):
    lo, la = math.radians(lon_deg), math.radians(lat_deg)
    r = MOON_RADIUS_KM + h_m / 1000.0
    cl = math.cos(la)
    return r * cl * math.cos(lo), r * cl * math.sin(lo), r * math.sin(la)


@njit(cache=True)
def _visible_samples(image, s, l, lon, lat, heights, row0, cx, cy, cz, out):
    nh, nw = heights.shape
    for bi in range(s.shape[0]):
        i = row0 + bi
        iu, idn = max(i - 1, 0), min(i + 1, nh - 1)
        fr = 0.5 if (i > 0 and i < nh - 1) else 1.0
        for j in range(s.shape[1]):
            out[bi, j] = np.nan
            h = heights[i, j]
            if not np.isfinite(h) or not np.isfinite(s[bi, j]) or not np.isfinite(l[bi, j]):
                continue
            jl, jr = max(j - 1, 0), min(j + 1, nw - 1)
            fc = 0.5 if (j > 0 and j < nw - 1) else 1.0
            ux, uy, uz = _point(lon[j], lat[iu], heights[iu, j])
            dx, dy, dz = _point(lon[j], lat[idn], heights[idn, j])
            lx, ly, lz = _point(lon[jl], lat[i], heights[i, jl])
            rx_, ry_, rz_ = _point(lon[jr], lat[i], heights[i, jr])
            rx, ry, rz = (dx - ux) * fr, (dy - uy) * fr, (dz - uz) * fr  # towards south
            ex, ey, ez = (rx_ - lx) * fc, (ry_ - ly) * fc, (rz_ - lz) * fc  # towards east
            nx, ny, nz = ry * ez - rz * ey, rz * ex - rx * ez, rx * ey - ry * ex
            px, py, pz = _point(lon[j], lat[i], h)
            norm = math.sqrt(nx * nx + ny * ny + nz * nz)
            if norm == 0.0:  # a grid one pixel high or wide has no slope across it: the radial normal
                nx, ny, nz = px, py, pz
                norm = math.sqrt(px * px + py * py + pz * pz)
            if nx * px + ny * py + nz * pz < 0:
                norm = -norm
            vx, vy, vz = cx - px, cy - py, cz - pz
            cos_e = (nx * vx + ny * vy + nz * vz) / norm / math.sqrt(vx * vx + vy * vy + vz * vz)
            if cos_e > 0:
                out[bi, j] = bilinear_at(image, s[bi, j] - 1.0, l[bi, j] - 1.0)


def sample_visible(image, s, l, lon, lat, heights, row0: int, spacecraft_km, out) -> None:
    """Fill ``out`` (rows ``row0 ...`` of the grid) with visible cube values; see the module docstring.

    ``s, l``: 1-based cube coordinates of those rows; ``lon`` (W,), ``lat`` (H,) degrees of
    the whole grid; ``heights`` (H, W) metres; ``spacecraft_km`` body-fixed position.
    """
    lon, lat = np.asarray(lon, np.float64), np.asarray(lat, np.float64)
    if lat.shape[0] < heights.shape[0] or lon.shape[0] < heights.shape[1]:  # the kernel reads them unchecked
        raise ValueError(f"{heights.shape} heights need as many latitudes and longitudes, got {lat.shape[0]} and {lon.shape[0]}")
    cx, cy, cz = (float(v) for v in spacecraft_km)
    _visible_samples(np.asarray(image), s, l, lon, lat, heights, int(row0), cx, cy, cz, out)
