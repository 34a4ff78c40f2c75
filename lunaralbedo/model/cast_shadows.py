r"""Cast shadows from a DEM: ground points whose ray to the Sun is blocked by terrain.

A ground point :math:`\mathbf{p}` (body-fixed, km; a DEM pixel centre at its height)
is in cast shadow when some point of its ray to the Sun,
:math:`\mathbf{q}(s) = \mathbf{p} + s\,\hat{\mathbf{l}}`, :math:`s > 0`, lies below the
terrain, i.e. :math:`|\mathbf{q}| < R + h(\lambda_q, \phi_q)/1000` with :math:`h` the
DEM height (metres, bilinear between pixel centres) under :math:`\mathbf{q}`.

The ray is marched in 3-D body-fixed coordinates, so the Moon's curvature is exact:
a ray leaving the ground horizontally is :math:`s^2/2R` above the sphere after
:math:`s` km (29 m at 10 km), which shortens long shadows (a 1 km wall under a Sun
1° high casts a 36 km shadow on the sphere, 57 km on a plane).  The march stops when
the ray is higher than the highest DEM point (it cannot be blocked any more) or
leaves the DEM grid (terrain beyond the grid cannot be seen: read the DEM with a
margin of :func:`shadow_reach_km` around the area of interest).

Frames and units: body-fixed km for positions, metres for heights above the
1737.4 km sphere, degrees for the north-up lon/lat grid (pixel centres at
``transform * (col + 0.5, row + 0.5)``).  Pure NumPy/numba, no I/O.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..constants import MOON_RADIUS_KM

#: March step, in pixels of the DEM grid (half a pixel: no ridge of the bilinear DEM is stepped over
#: by more than half a pixel).
STEP_PX = 0.5
#: The ray must be this far below the bilinear terrain to count as blocked (metres): keeps the
#: first half-pixel steps on a smoothly curved slope (bilinear chords) from shadowing the point itself.
TOLERANCE_M = 0.5
#: Longest shadow searched for (km); terrain farther than this from a point is not considered.
MAX_REACH_KM = 150.0


def sun_elevation(points_km: np.ndarray, sun_km) -> np.ndarray:
    """Elevation (radians) of the Sun above the local horizon of the sphere at each point ``(..., 3)``."""
    p = np.asarray(points_km, dtype=np.float64)
    up = p / np.linalg.norm(p, axis=-1, keepdims=True)
    l = np.asarray(sun_km, dtype=np.float64) - p
    l /= np.linalg.norm(l, axis=-1, keepdims=True)
    return np.arcsin(np.clip(np.einsum("...i,...i->...", up, l), -1.0, 1.0))


def shadow_reach_km(relief_m: float, elevation_rad: float, max_km: float = MAX_REACH_KM) -> float:
    r"""Longest shadow (km) that terrain ``relief_m`` high can cast with the Sun ``elevation_rad`` high.

    On the sphere a ray rising at elevation :math:`\epsilon` is
    :math:`s\tan\epsilon + s^2/2R` above the start after :math:`s` km; the reach is the
    :math:`s` where that equals the relief, capped at ``max_km``.
    """
    h = max(float(relief_m), 0.0) / 1000.0
    t = math.tan(max(float(elevation_rad), 0.0))
    a = 1.0 / (2.0 * MOON_RADIUS_KM)
    s = (-t + math.sqrt(t * t + 4.0 * a * h)) / (2.0 * a)
    return min(s, max_km)


#: Side of the blocks (pixels) whose maximum height lets a ray skip terrain it is already above.
BLOCK_PX = 8
#: Safety factor on the terrain's slope bound (second-order effects of the lon/lat grid over the reach).
SLOPE_SAFETY = 1.05


@njit(cache=True)
def _block_max(dem, b):
    """Max height (NaN ignored, -inf if none) over each ``b`` x ``b`` block and its 8 neighbour blocks."""
    h_, w_ = dem.shape
    nr, nc = (h_ + b - 1) // b, (w_ + b - 1) // b
    own = np.full((nr, nc), -np.inf)
    for i in range(h_):
        for j in range(w_):
            v = dem[i, j]
            if v == v and v > own[i // b, j // b]:
                own[i // b, j // b] = v
    out = np.full((nr, nc), -np.inf)
    for bi in range(nr):
        for bj in range(nc):
            m = -np.inf
            for di in range(max(bi - 1, 0), min(bi + 2, nr)):
                for dj in range(max(bj - 1, 0), min(bj + 2, nc)):
                    if own[di, dj] > m:
                        m = own[di, dj]
            out[bi, bj] = m
    return out


@njit(cache=True)
def _slope_bound(dem, px_x_km, px_y_km):
    """Upper bound of the bilinear terrain's rise per km of ground distance (m/km): max |dh| between
    neighbours along x over the smallest x pixel, plus the same along y (NaN neighbours ignored)."""
    h_, w_ = dem.shape
    gx = 0.0
    gy = 0.0
    for i in range(h_):
        for j in range(w_):
            v = dem[i, j]
            if v != v:
                continue
            if j + 1 < w_ and dem[i, j + 1] == dem[i, j + 1]:
                gx = max(gx, abs(dem[i, j + 1] - v))
            if i + 1 < h_ and dem[i + 1, j] == dem[i + 1, j]:
                gy = max(gy, abs(dem[i + 1, j] - v))
    return gx / px_x_km + gy / px_y_km


@njit(cache=True)
def _march(dem, lon0, dlon, lat0, dlat, sun, r0, r1, c0, c1, step_km, max_steps, hmax_m, tol_m, radius,
           slope, bmax, block, skip):
    """March every window pixel's ray to the Sun (see the module docstring); True where it is blocked.

    Two shortcuts that never change the answer: a pixel whose Sun is higher than the terrain's
    steepest possible rise (``slope``, m/km; 0 disables) cannot be shadowed; and while the ray
    is above ``bmax`` (the maximum over its ``block``-pixel block and the blocks around it) and
    rising, the next ``skip`` steps (which stay within that neighbourhood) cannot be blocked.
    """
    h_, w_ = dem.shape
    out = np.zeros((r1 - r0, c1 - c0), np.bool_)
    d2r = math.pi / 180.0
    lon_mid = lon0 + dlon * w_ / 2.0
    for i in range(r0, r1):
        lat = (lat0 + (i + 0.5) * dlat) * d2r
        for j in range(c0, c1):
            h = dem[i, j]
            if not np.isfinite(h):
                continue
            lon = (lon0 + (j + 0.5) * dlon) * d2r
            r = radius + h / 1000.0
            px, py, pz = r * math.cos(lat) * math.cos(lon), r * math.cos(lat) * math.sin(lon), r * math.sin(lat)
            lx, ly, lz = sun[0] - px, sun[1] - py, sun[2] - pz
            n = math.sqrt(lx * lx + ly * ly + lz * lz)
            lx, ly, lz = lx / n, ly / n, lz / n
            sin_e = (px * lx + py * ly + pz * lz) / r  # the ray's elevation above the sphere's horizon
            rising = sin_e > 0.0
            if slope > 0.0 and rising and sin_e >= 0.001 * slope * math.sqrt(max(1.0 - sin_e * sin_e, 0.0)):
                continue  # tan(e) >= the steepest rise of the terrain: nothing can block this ray
            s = 1
            while s <= max_steps:
                qx, qy, qz = px + s * step_km * lx, py + s * step_km * ly, pz + s * step_km * lz
                rq = math.sqrt(qx * qx + qy * qy + qz * qz)
                hray = (rq - radius) * 1000.0
                if hray > hmax_m:
                    break
                lonq = math.atan2(qy, qx) / d2r
                lonq = lon_mid + ((lonq - lon_mid + 180.0) % 360.0 - 180.0)
                latq = math.asin(qz / rq) / d2r
                x = (lonq - lon0) / dlon - 0.5
                y = (latq - lat0) / dlat - 0.5
                if x < 0.0 or y < 0.0 or x > w_ - 1 or y > h_ - 1:
                    break
                ix, iy = min(int(x), w_ - 2), min(int(y), h_ - 2)
                if skip > 1 and rising and hray >= bmax[iy // block, ix // block] - tol_m:
                    s += skip  # above all terrain within reach of the next `skip` steps
                    continue
                fx, fy = x - ix, y - iy
                z = ((dem[iy, ix] * (1 - fx) + dem[iy, ix + 1] * fx) * (1 - fy)
                     + (dem[iy + 1, ix] * (1 - fx) + dem[iy + 1, ix + 1] * fx) * fy)
                if np.isfinite(z) and hray < z - tol_m:
                    out[i - r0, j - c0] = True
                    break
                s += 1
    return out


def cast_shadow_mask(dem_m, transform, sun_km, window=None, *, max_reach_km: float = MAX_REACH_KM,
                     step_px: float = STEP_PX, tolerance_m: float = TOLERANCE_M, shortcuts: bool = True) -> np.ndarray:
    """True where a DEM pixel centre is in the cast shadow of the terrain for the Sun at ``sun_km``.

    ``dem_m``: heights (metres above the 1737.4 km sphere, NaN where unknown) on the
    north-up lon/lat grid of the affine ``transform`` (degrees); ``sun_km``: Sun
    position, body-fixed km; ``window``: ``(row0, row1, col0, col1)`` of the pixels to
    decide (default: all; the rest of the grid is the margin that can cast shadows
    into it).  Returns a bool array of the window's shape.  Pixels whose own height is
    NaN are reported lit (they have no ground point); NaN terrain blocks nothing.

    ``shortcuts`` (default) skips rays that the terrain's steepest slope cannot block and
    steps over terrain the ray is already above (:func:`_march`); the mask is the same
    without them, only slower (``tests/test_cast_shadows.py`` compares both).
    """
    dem = np.ascontiguousarray(dem_m, dtype=np.float64)
    h, w = dem.shape
    r0, r1, c0, c1 = window if window is not None else (0, h, 0, w)
    if h < 2 or w < 2 or not np.isfinite(dem).any():
        return np.zeros((r1 - r0, c1 - c0), bool)
    lat_mid = math.radians(transform.f + transform.e * h / 2.0)
    km_per_deg = math.radians(1.0) * MOON_RADIUS_KM
    px_km = km_per_deg * min(abs(transform.a) * max(math.cos(lat_mid), 1e-3), abs(transform.e))
    step_km = step_px * px_km
    max_steps = max(1, int(math.ceil(max_reach_km / step_km)))
    hmax = float(np.nanmax(dem))
    # the smallest pixel anywhere on the grid (longitude pixels shrink towards the poles)
    lat_far = max(abs(transform.f), abs(transform.f + transform.e * h))
    px_x_min = km_per_deg * abs(transform.a) * math.cos(math.radians(min(lat_far, 90.0)))
    px_y = km_per_deg * abs(transform.e)
    slope, bmax, skip = 0.0, np.zeros((1, 1)), 0
    if shortcuts and px_x_min > 1e-9:
        slope = SLOPE_SAFETY * _slope_bound(dem, px_x_min, px_y)
        bmax = _block_max(dem, BLOCK_PX)
        # one step moves the ray at most step_km / min(px_x_min, px_y) pixels over the ground; positions
        # within BLOCK_PX - 1 pixels of the current one interpolate inside the block neighbourhood of bmax
        skip = int(math.floor((BLOCK_PX - 1) * min(px_x_min, px_y) / (SLOPE_SAFETY * step_km)))
    return _march(dem, float(transform.c), float(transform.a), float(transform.f), float(transform.e),
                  np.asarray(sun_km, dtype=np.float64), int(r0), int(r1), int(c0), int(c1), step_km, max_steps,
                  hmax, float(tolerance_m), MOON_RADIUS_KM, slope, bmax, BLOCK_PX, skip)
