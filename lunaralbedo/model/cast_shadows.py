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


#: Cells (pixels) of the coarse maximum-height grid the march uses to skip steps that cannot be blocked.
CELL_PX = 8
#: Safety factor on the terrain's slope bound (second-order effects of the lon/lat grid over the reach).
SLOPE_SAFETY = 1.05


@njit(cache=True)
def _slope_bound(dem, px_x_km, px_y_km):
    """Upper bound of the bilinear terrain's rise per km of ground distance (m/km): the largest |dh|
    between neighbours along x over the smallest x pixel, plus the same along y (NaN neighbours ignored)."""
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


def slope_bound(dem_m, transform) -> float:
    r"""The steepest rise (m per km of ground) the bilinear terrain can have anywhere on the grid, x 1.05.

    A ray whose Sun is higher than this (:math:`	an\epsilon \ge` bound / 1000) cannot be
    blocked: it rises at least :math:`s\sin\epsilon` over a ground distance of at most
    :math:`s\cos\epsilon`, along which the terrain rises at most bound x distance.  0 when
    the grid reaches a pole (no bound).
    """
    dem = _as_heights(dem_m)
    h = dem.shape[0]
    km_per_deg = math.radians(1.0) * (MOON_RADIUS_KM - 20.0)  # the lowest radius a sample can have
    far = max(abs(transform.f), abs(transform.f + transform.e * h))
    if far >= 89.0 or h < 2:
        return 0.0
    px_x = km_per_deg * abs(transform.a) * math.cos(math.radians(far))
    return SLOPE_SAFETY * float(_slope_bound(dem, px_x, km_per_deg * abs(transform.e)))


@njit(cache=True)
def _cell_max(dem, cell):
    """Highest height of every ``cell`` x ``cell`` block plus its next row and column (bilinear neighbours),
    then the maximum over the 3 x 3 blocks around it; -inf where no height."""
    h_, w_ = dem.shape
    ni, nj = (h_ + cell - 1) // cell, (w_ + cell - 1) // cell
    cm = np.full((ni, nj), -np.inf)
    for i in range(h_):
        for j in range(w_):
            v = dem[i, j]
            if v != v:
                continue
            for bi in range(max(i - 1, 0) // cell, i // cell + 1):
                for bj in range(max(j - 1, 0) // cell, j // cell + 1):
                    if v > cm[bi, bj]:
                        cm[bi, bj] = v
    dm = np.full((ni, nj), -np.inf)
    for bi in range(ni):
        for bj in range(nj):
            m = -np.inf
            for ii in range(max(bi - 1, 0), min(bi + 2, ni)):
                for jj in range(max(bj - 1, 0), min(bj + 2, nj)):
                    m = max(m, cm[ii, jj])
            dm[bi, bj] = m
    return dm


@njit(cache=True, inline="always")
def _shadowed(dem, lon0, dlon, lat0, dlat, sun, i, j, step_km, max_steps, hmax_m, tol_m, radius, lon_mid,
              near_max, cell, skip, slope):
    """Is DEM pixel ``(i, j)`` in the cast shadow (the one march of every caller)?

    Steps whose ray is above every height within ``cell`` pixels (``near_max``, the 3 x 3
    cells around the sample) cannot be blocked, nor can the next ``skip`` steps, which stay
    within those cells while the ray keeps rising (Sun above the point's horizon): they are
    skipped, so the answer is the full march's at a fraction of the steps.  A ray whose Sun
    is higher than the terrain's steepest rise (``slope``, m/km, :func:`slope_bound`; 0: no
    bound) cannot be blocked and is not marched at all.
    """
    h_, w_ = dem.shape
    d2r = math.pi / 180.0
    h = dem[i, j]
    if not np.isfinite(h):
        return False
    lat = (lat0 + (i + 0.5) * dlat) * d2r
    lon = (lon0 + (j + 0.5) * dlon) * d2r
    r = radius + h / 1000.0
    px, py, pz = r * math.cos(lat) * math.cos(lon), r * math.cos(lat) * math.sin(lon), r * math.sin(lat)
    lx, ly, lz = sun[0] - px, sun[1] - py, sun[2] - pz
    n = math.sqrt(lx * lx + ly * ly + lz * lz)
    lx, ly, lz = lx / n, ly / n, lz / n
    sin_e = (px * lx + py * ly + pz * lz) / r  # the Sun's elevation above the point's horizon
    if slope > 0.0 and sin_e > 0.0 and sin_e >= 0.001 * slope * math.sqrt(max(1.0 - sin_e * sin_e, 0.0)):
        return False  # tan(e) >= the steepest rise of the terrain
    rising = skip > 0 and sin_e >= 0.0  # |p + s l| grows with s
    s = 1
    while s <= max_steps:
        qx, qy, qz = px + s * step_km * lx, py + s * step_km * ly, pz + s * step_km * lz
        rq = math.sqrt(qx * qx + qy * qy + qz * qz)
        hray = (rq - radius) * 1000.0
        if hray > hmax_m:
            return False
        lonq = math.atan2(qy, qx) / d2r
        lonq = lon_mid + ((lonq - lon_mid + 180.0) % 360.0 - 180.0)
        latq = math.asin(qz / rq) / d2r
        x = (lonq - lon0) / dlon - 0.5
        y = (latq - lat0) / dlat - 0.5
        if x < 0.0 or y < 0.0 or x > w_ - 1 or y > h_ - 1:
            return False
        ix, iy = min(int(x), w_ - 2), min(int(y), h_ - 2)
        fx, fy = x - ix, y - iy
        z = ((dem[iy, ix] * (1 - fx) + dem[iy, ix + 1] * fx) * (1 - fy)
             + (dem[iy + 1, ix] * (1 - fx) + dem[iy + 1, ix + 1] * fx) * fy)
        if np.isfinite(z) and hray < z - tol_m:
            return True
        if rising and hray >= near_max[iy // cell, ix // cell] - tol_m:
            s += skip
        s += 1
    return False


@njit(cache=True)
def _march(dem, lon0, dlon, lat0, dlat, sun, r0, r1, c0, c1, step_km, max_steps, hmax_m, tol_m, radius,
           near_max, cell, skip, slope):
    out = np.zeros((r1 - r0, c1 - c0), np.bool_)
    lon_mid = lon0 + dlon * dem.shape[1] / 2.0
    for i in range(r0, r1):
        for j in range(c0, c1):
            out[i - r0, j - c0] = _shadowed(dem, lon0, dlon, lat0, dlat, sun, i, j, step_km, max_steps, hmax_m,
                                            tol_m, radius, lon_mid, near_max, cell, skip, slope)
    return out


@njit(cache=True)
def _march_pixels(dem, lon0, dlon, lat0, dlat, sun, rows, cols, step_km, max_steps, hmax_m, tol_m, radius,
                  near_max, cell, skip, slope):
    out = np.zeros(rows.shape[0], np.bool_)
    lon_mid = lon0 + dlon * dem.shape[1] / 2.0
    for o in range(rows.shape[0]):
        out[o] = _shadowed(dem, lon0, dlon, lat0, dlat, sun, rows[o], cols[o], step_km, max_steps, hmax_m,
                           tol_m, radius, lon_mid, near_max, cell, skip, slope)
    return out


def _skip_steps(transform, shape, step_km: float, cell: int) -> int:
    """Steps that certainly stay within ``cell - 1`` pixels of the grid (0: never skip)."""
    h, w = shape
    lats = (transform.f, transform.f + transform.e * h)
    far = max(abs(v) for v in lats)
    if cell < 2 or far >= 89.0:
        return 0
    low = MOON_RADIUS_KM - 20.0  # lowest radius a sample can have (km): below every lunar height
    px_km = math.radians(1.0) * low * min(abs(transform.a) * math.cos(math.radians(far)), abs(transform.e))
    return max(0, int((cell - 1) / (1.01 * step_km / px_km)) - 1)


def _as_heights(dem_m) -> np.ndarray:
    """Heights as a C-contiguous float32 or float64 array (float32 is marched as is: the same answers, half the memory)."""
    dem = np.asarray(dem_m)
    return np.ascontiguousarray(dem, dtype=dem.dtype if dem.dtype in (np.float32, np.float64) else np.float64)


def _march_args(dem_m, transform, step_px, max_reach_km):
    dem = _as_heights(dem_m)
    h, w = dem.shape
    lat_mid = math.radians(transform.f + transform.e * h / 2.0)
    px_km = math.radians(1.0) * MOON_RADIUS_KM * min(abs(transform.a) * max(math.cos(lat_mid), 1e-3), abs(transform.e))
    step_km = step_px * px_km
    max_steps = max(1, int(math.ceil(max_reach_km / step_km)))
    return dem, (float(transform.c), float(transform.a), float(transform.f), float(transform.e)), step_km, max_steps


def cast_shadow_mask(dem_m, transform, sun_km, window=None, *, max_reach_km: float = MAX_REACH_KM,
                     step_px: float = STEP_PX, tolerance_m: float = TOLERANCE_M, skip: bool = True) -> np.ndarray:
    """True where a DEM pixel centre is in the cast shadow of the terrain for the Sun at ``sun_km``.

    ``dem_m``: heights (metres above the 1737.4 km sphere, NaN where unknown) on the
    north-up lon/lat grid of the affine ``transform`` (degrees); ``sun_km``: Sun
    position, body-fixed km; ``window``: ``(row0, row1, col0, col1)`` of the pixels to
    decide (default: all; the rest of the grid is the margin that can cast shadows
    into it).  Returns a bool array of the window's shape.  Pixels whose own height is
    NaN are reported lit (they have no ground point); NaN terrain blocks nothing.
    ``skip=False`` marches every step of every ray (the reference the shortcuts are tested against).
    """
    h, w = np.shape(dem_m)
    r0, r1, c0, c1 = window if window is not None else (0, h, 0, w)
    if h < 2 or w < 2 or not np.isfinite(dem_m).any():
        return np.zeros((r1 - r0, c1 - c0), bool)
    dem, grid, step_km, max_steps = _march_args(dem_m, transform, step_px, max_reach_km)
    near, n_skip = near_maximum(dem), (_skip_steps(transform, dem.shape, step_km, CELL_PX) if skip else 0)
    return _march(dem, *grid, np.asarray(sun_km, dtype=np.float64), int(r0), int(r1), int(c0), int(c1), step_km,
                  max_steps, float(np.nanmax(dem)), float(tolerance_m), MOON_RADIUS_KM, near, CELL_PX, n_skip,
                  slope_bound(dem, transform) if skip else 0.0)


def near_maximum(dem_m) -> np.ndarray:
    """The coarse maximum-height grid of a DEM that lets the march skip steps (:data:`CELL_PX` pixel cells)."""
    return _cell_max(_as_heights(dem_m), CELL_PX)


def cast_shadow_pixels(dem_m, transform, sun_km, rows, cols, *, hmax_m: float | None = None, near_max=None,
                       slope: float | None = None,
                       max_reach_km: float = MAX_REACH_KM, step_px: float = STEP_PX,
                       tolerance_m: float = TOLERANCE_M) -> np.ndarray:
    """:func:`cast_shadow_mask` of the DEM pixels ``(rows[o], cols[o])`` only (1-D bool).

    The same march pixel by pixel, so the answers equal the mask's at those pixels; the
    solver asks only for pixels that would otherwise be observations.  ``dem_m`` should
    already be float32 or float64 and C-contiguous (it is not copied then); ``hmax_m``: its maximum
    (finite) height, ``near_max`` its :func:`near_maximum` and ``slope`` its :func:`slope_bound`, when the
    caller has them.
    """
    rows = np.ascontiguousarray(rows, dtype=np.int64)
    cols = np.ascontiguousarray(cols, dtype=np.int64)
    h, w = np.shape(dem_m)
    if h < 2 or w < 2 or rows.size == 0:
        return np.zeros(rows.shape, bool)
    dem, grid, step_km, max_steps = _march_args(dem_m, transform, step_px, max_reach_km)
    if hmax_m is None:
        if not np.isfinite(dem).any():
            return np.zeros(rows.shape, bool)
        hmax_m = float(np.nanmax(dem))
    near = near_maximum(dem) if near_max is None else near_max
    return _march_pixels(dem, *grid, np.asarray(sun_km, dtype=np.float64), rows, cols, step_km, max_steps,
                         float(hmax_m), float(tolerance_m), MOON_RADIUS_KM, near, CELL_PX,
                         _skip_steps(transform, dem.shape, step_km, CELL_PX),
                         slope_bound(dem, transform) if slope is None else float(slope))
