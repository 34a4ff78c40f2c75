r"""The march of cast-shadow rays over a DEM grid: numba kernels of :mod:`.cast_shadows`.

One ray per pixel from its ground point towards the Sun, sampled every ``step_km`` on the
bilinear DEM, with the shortcuts of :class:`~.cast_shadows.MarchGrid` (global slope bound,
maximum-height and slope pyramid).  Body-fixed km, heights in metres above the 1737.4 km
sphere, north-up lon/lat grids in degrees (pixel centres at ``transform * (col + 0.5, row + 0.5)``).
Pure numba, no I/O.  Kept in one file: numba's cache checks only a function's own file, and
the samplers are inlined into the march.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

# atan(t) = t - t^3/3 + t^5/5 - ... for |t| <= ATAN_SERIES_MAX, to t^15: an alternating series whose
# truncation error is below its first dropped term, 0.1^17 / 17 = 6e-19 rad.
ATAN_SERIES_MAX = 0.1
_A3, _A5, _A7, _A9, _A11, _A13, _A15 = -1 / 3, 1 / 5, -1 / 7, 1 / 9, -1 / 11, 1 / 13, -1 / 15


@njit(cache=True, inline="always")
def _angle(num, den):
    """atan2(num, den) for den > 0 and |num| <= 0.1 den by the series (no libm call), else atan2 itself."""
    if den > 0.0 and abs(num) <= ATAN_SERIES_MAX * den:
        t = num / den
        u = t * t
        return t * (1.0 + u * (_A3 + u * (_A5 + u * (_A7 + u * (_A9 + u * (_A11 + u * (_A13 + u * _A15)))))))
    return math.atan2(num, den)


@njit(cache=True, inline="always")
def _sample_xy(qx, qy, qz, cos_lon, sin_lon, cos_lat, sin_lat, i, j, kx, ky):
    r"""Grid coordinates (fractional col, row) of the point ``q`` (km) seen from pixel ``(i, j)``, without trig calls.

    The longitude and latitude of ``q`` relative to the pixel's :math:`(\lambda_j, \phi_i)`
    (their cosines and sines from the tables) are
    :math:`\Delta\lambda = \operatorname{atan2}(q_y\cos\lambda_j - q_x\sin\lambda_j,\ q_x\cos\lambda_j + q_y\sin\lambda_j)`,
    :math:`\Delta\phi = \operatorname{atan2}(q_z\cos\phi_i - \rho\sin\phi_i,\ \rho\cos\phi_i + q_z\sin\phi_i)`,
    :math:`\rho = \sqrt{q_x^2 + q_y^2}` (exact identities), both angles below 0.1 rad within
    :data:`MAX_REACH_KM` of a pixel below 60° of latitude, where :func:`_angle` sums the series;
    ``kx``, ``ky``: pixels per radian.  Error against ``atan2``/``asin`` of ``q`` (the exact
    conversion): the series' 6e-19 rad plus rounding, below 1e-9 px (``tests/test_cast_shadows.py``).
    """
    dlon = _angle(qy * cos_lon - qx * sin_lon, qx * cos_lon + qy * sin_lon)
    rho = math.sqrt(qx * qx + qy * qy)
    dlat = _angle(qz * cos_lat - rho * sin_lat, rho * cos_lat + qz * sin_lat)
    return j + dlon * kx, i + dlat * ky


@njit(cache=True, inline="always")
def _sample_xy_exact(qx, qy, qz, lon0, dlon, lat0, dlat, lon_mid):
    """Grid coordinates of ``q`` from its longitude (``atan2``, wrapped near ``lon_mid``) and latitude (``asin``)."""
    d2r = math.pi / 180.0
    rq = math.sqrt(qx * qx + qy * qy + qz * qz)
    lonq = math.atan2(qy, qx) / d2r
    lonq = lon_mid + ((lonq - lon_mid + 180.0) % 360.0 - 180.0)
    latq = math.asin(qz / rq) / d2r
    return (lonq - lon0) / dlon - 0.5, (latq - lat0) / dlat - 0.5


@njit(cache=True, nogil=True)
def _trig_tables(lon0, dlon, w, lat0, dlat, h, row0=0):
    """Cosines and sines of the pixel-centre longitudes and latitudes (radians from ``transform * (c + 0.5, r + 0.5)``)
    of rows ``row0:row0 + h`` of the grid."""
    d2r = math.pi / 180.0
    cos_lon, sin_lon, cos_lat, sin_lat = np.empty(w), np.empty(w), np.empty(h), np.empty(h)
    for j in range(w):
        lon = (lon0 + (j + 0.5) * dlon) * d2r
        cos_lon[j], sin_lon[j] = math.cos(lon), math.sin(lon)
    for i in range(h):
        lat = (lat0 + (i + row0 + 0.5) * dlat) * d2r
        cos_lat[i], sin_lat[i] = math.cos(lat), math.sin(lat)
    return cos_lon, sin_lon, cos_lat, sin_lat


@njit(cache=True, nogil=True)
def _march_pixels(dem, prm, max_steps, exact, decide, cos_lon, sin_lon, cos_lat, sin_lat, sun, rows, cols,
                  lev_top, lev_slope, lev_off, lev_width, lev_shift, lev_skip, lit, bi0, bj0, shift, out):
    """The march of every pixel ``(rows[o], cols[o])`` into ``out[o]``: 1 shadowed, 0 lit, 2 (``decide``) not
    answered by the global slope bound (``prm[8]``; 0: none); ``prm[9]``, ``prm[10]``: offsets of rows, columns;
    ``prm[11]`` (if given): the grid row of ``dem``'s first row when ``dem`` is a band of rows of the grid whose
    ``prm[0:4]`` and tables these are (the samples' coordinates are the grid's, as for the whole grid: the same bits;
    a ray leaving the band is lit, as one leaving the grid).
    A pixel whose block is flagged in ``lit`` (:func:`lit_cells` from block ``bi0, bj0``; blocks of ``1 << shift``
    pixels; empty: none) is lit without a march (its ``out`` is left as it is)."""
    lon0, dlon, lat0, dlat, step_km, hmax_m, tol_m, radius, slope = prm[0], prm[1], prm[2], prm[3], prm[4], \
        prm[5], prm[6], prm[7], prm[8]
    roff, coff = int(prm[9]), int(prm[10])
    rb = int(prm[11]) if prm.shape[0] > 11 else 0
    h_, w_ = dem.shape
    lon_mid = lon0 + dlon * w_ / 2.0
    d2r = math.pi / 180.0
    kx, ky = 1.0 / (d2r * dlon), 1.0 / (d2r * dlat)
    n_lev = lev_shift.shape[0]
    flagged = lit.shape[0] > 0
    for o in range(rows.shape[0]):
        i, j = roff + np.int64(rows[o]), coff + np.int64(cols[o])
        if flagged and lit[(i >> shift) - bi0, (j >> shift) - bj0]:
            continue  # a block known lit: every pixel of it is
        h = dem[i, j]
        if not np.isfinite(h):
            continue  # no ground point: lit
        r = radius + h / 1000.0
        px, py, pz = r * cos_lat[i] * cos_lon[j], r * cos_lat[i] * sin_lon[j], r * sin_lat[i]
        lx, ly, lz = sun[0] - px, sun[1] - py, sun[2] - pz
        n = math.sqrt(lx * lx + ly * ly + lz * lz)
        lx, ly, lz = lx / n, ly / n, lz / n
        sin_e = (px * lx + py * ly + pz * lz) / r  # the Sun's elevation above the point's horizon
        cos_e = math.sqrt(max(1.0 - sin_e * sin_e, 0.0))
        if slope > 0.0 and sin_e > 0.0 and sin_e >= 0.001 * slope * cos_e:
            continue  # tan(e) >= the steepest rise of the terrain: lit
        if decide:
            out[o] = 2
            continue
        rising = n_lev > 0 and sin_e >= 0.0  # |p + s l| grows with s, and the Sun's elevation along the ray
        rise = 1000.0 * sin_e / cos_e if cos_e > 0.0 else np.inf  # m per km of ground, at least, from any sample
        hray, ix, iy = h - 1e-6, j, i  # the start: the ray at the pixel's own height (less any rounding)
        s = 0
        while True:
            if rising:  # the coarsest level whose 3 x 3 cells around the sample the next steps cannot reach into
                lev = 0
                while lev < n_lev:
                    k = lev_off[lev] + (iy >> lev_shift[lev]) * lev_width[lev] + (ix >> lev_shift[lev])
                    if hray >= lev_top[k] - tol_m or rise >= lev_slope[k]:
                        lev += 1
                    else:
                        break
                if lev > 0:
                    s += lev_skip[lev - 1]
                    if h + 1000.0 * (s + 1) * step_km * sin_e > hmax_m + 1e-3:
                        break  # the next sample is certainly above every height: lit, as the march would find
            s += 1
            if s > max_steps:
                break
            qx, qy, qz = px + s * step_km * lx, py + s * step_km * ly, pz + s * step_km * lz
            rq = math.sqrt(qx * qx + qy * qy + qz * qz)
            hray = (rq - radius) * 1000.0
            if hray > hmax_m:
                break
            if exact:
                x, y = _sample_xy_exact(qx, qy, qz, lon0, dlon, lat0, dlat, lon_mid)
            else:
                x, y = _sample_xy(qx, qy, qz, cos_lon[j], sin_lon[j], cos_lat[i], sin_lat[i], i + rb, j, kx, ky)
            if x < 0.0 or y < rb or x > w_ - 1 or y > rb + h_ - 1:
                break
            ix, iy = min(int(x), w_ - 2), min(int(y), rb + h_ - 2)
            fx, fy = x - ix, y - iy
            iy -= rb  # the grid's row -> dem's
            z = ((dem[iy, ix] * (1 - fx) + dem[iy, ix + 1] * fx) * (1 - fy)
                 + (dem[iy + 1, ix] * (1 - fx) + dem[iy + 1, ix + 1] * fx) * fy)
            if np.isfinite(z) and hray < z - tol_m:
                out[o] = 1
                break


@njit(cache=True, inline="always")
def _levels_passed(lev_top, lev_slope, lev_off, lev_width, lev_shift, iy, ix, hray, rise, tol_m):
    """How many pyramid levels, from the finest, have a ray at ``hray`` (m) rising at least ``rise`` (m/km) above the
    highest height or steeper than the slope bound of the 3 x 3 cells around DEM pixel ``(iy, ix)``."""
    lev = 0
    while lev < lev_shift.shape[0]:
        k = lev_off[lev] + (iy >> lev_shift[lev]) * lev_width[lev] + (ix >> lev_shift[lev])
        if hray >= lev_top[k] - tol_m or rise >= lev_slope[k]:
            lev += 1
        else:
            break
    return lev


@njit(cache=True, nogil=True)
def _corner_angle(lat, dlat_half, dlon_half):
    """Largest angle (rad) between the unit vector at latitude ``lat`` and those at ``lat +- dlat_half``,
    longitude ``+- dlon_half`` (radians): the corners of a lon/lat box, where its farthest points from its centre are."""
    ux, uz = math.cos(lat), math.sin(lat)
    worst = 0.0
    for a in (lat - dlat_half, lat + dlat_half):
        vx, vy, vz = math.cos(a) * math.cos(dlon_half), math.cos(a) * math.sin(dlon_half), math.sin(a)
        cx, cy, cz = -uz * vy, uz * vx - ux * vz, ux * vy  # u x v with u = (ux, 0, uz)
        worst = max(worst, math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ux * vx + uz * vz))
    return worst


@njit(cache=True, inline="always")
def sine_floor(ux, uy, uz, rc, sun, theta, d):
    r"""A lower bound of the sine of the Sun's elevation above the horizon of every ground point within ``d`` km
    of :math:`\mathbf{p}_c = r_c\hat{\mathbf{u}}` whose vertical is within ``theta`` (rad) of :math:`\hat{\mathbf{u}}`:
    :math:`\sin\epsilon = \hat{\mathbf{u}}'\cdot\hat{\mathbf{l}}' \ge \hat{\mathbf{u}}\cdot\hat{\mathbf{l}}
    - |\hat{\mathbf{u}}' - \hat{\mathbf{u}}| - |\hat{\mathbf{l}}' - \hat{\mathbf{l}}|` with
    :math:`|\hat{\mathbf{u}}' - \hat{\mathbf{u}}| \le \theta` (a chord is shorter than its angle) and
    :math:`|\hat{\mathbf{l}}' - \hat{\mathbf{l}}| \le 2d/|\mathbf{s} - \mathbf{p}_c|`
    (:math:`|\mathbf{x}/|\mathbf{x}| - \mathbf{y}/|\mathbf{y}|| \le 2|\mathbf{x} - \mathbf{y}|/|\mathbf{y}|`), less 1e-12 for rounding."""
    lx, ly, lz = sun[0] - rc * ux, sun[1] - rc * uy, sun[2] - rc * uz
    n = math.sqrt(lx * lx + ly * ly + lz * lz)
    return (ux * lx + uy * ly + uz * lz) / n - theta - 2.0 * d / n - 1e-12


@njit(cache=True, nogil=True)
def lit_cells(low, top, prm, sun, bi0, bi1, bj0, bj1, cell, lev_top, lev_slope, lev_off, lev_width, lev_shift, lev_skip):
    r"""1 for every ``cell`` x ``cell`` block of the DEM grid (rows ``bi0:bi1``, columns ``bj0:bj1`` of blocks)
    all of whose pixels the march would find lit before its first sample; 0: not known.

    ``low``, ``top``: each block's lowest finite height (inf: none) and an upper bound of its
    heights (m); ``prm`` as :func:`_march_pixels`.  The march's first tests are monotone in
    the pixel's height :math:`h` and the Sun's elevation :math:`\epsilon` above its horizon
    (a ray at least as high and at least as steep passes them too), so they are run once per
    block with the block's lowest height and :func:`sine_floor` at the block's centre on the
    sphere at that height, ``theta`` (x 1.01) the largest angle between the vertical there
    and at a corner of the box of the pixel centres, ``d`` bounding the distance to any
    pixel's ground point.  A 1 is then the answer of every pixel of the
    block: the global slope bound, or every level letting the rising ray skip to where its next
    sample is above the highest height (:func:`_march_pixels`).
    """
    lon0, dlon, lat0, dlat, step_km, hmax_m, tol_m, radius, slope = prm[0], prm[1], prm[2], prm[3], prm[4], \
        prm[5], prm[6], prm[7], prm[8]
    d2r = math.pi / 180.0
    half = (cell - 1) / 2.0  # pixel centres from the block's centre, in pixels
    out = np.zeros((bi1 - bi0, bj1 - bj0), np.int8)
    cos_lon, sin_lon = np.empty(bj1 - bj0), np.empty(bj1 - bj0)
    for bj in range(bj0, bj1):
        lon = (lon0 + dlon * (bj * cell + cell / 2.0)) * d2r
        cos_lon[bj - bj0], sin_lon[bj - bj0] = math.cos(lon), math.sin(lon)
    for bi in range(bi0, bi1):
        lat = (lat0 + dlat * (bi * cell + cell / 2.0)) * d2r
        theta = 1.01 * _corner_angle(lat, abs(dlat) * half * d2r, abs(dlon) * half * d2r) + 1e-12
        cl, sl = math.cos(lat), math.sin(lat)
        for bj in range(bj0, bj1):
            lo = low[bi, bj]
            if not lo < np.inf:
                out[bi - bi0, bj - bj0] = 1  # no ground point in the block: every pixel lit
                continue
            sin_m = sine_floor(cl * cos_lon[bj - bj0], cl * sin_lon[bj - bj0], sl, radius + lo / 1000.0, sun, theta,
                               (top[bi, bj] - lo) / 1000.0 + (radius + top[bi, bj] / 1000.0) * theta)
            if not sin_m > 0.0:
                continue
            cos_m = math.sqrt(1.0 - sin_m * sin_m)  # >= cos(e) of every pixel
            if slope > 0.0 and sin_m >= 0.001 * slope * cos_m:
                out[bi - bi0, bj - bj0] = 1
                continue
            if lev_shift.shape[0] == 0:
                continue
            lev = _levels_passed(lev_top, lev_slope, lev_off, lev_width, lev_shift, bi * cell, bj * cell, lo - 1e-6,
                                 1000.0 * sin_m / cos_m, tol_m)
            if lev > 0 and lo + 1000.0 * (lev_skip[lev - 1] + 1) * step_km * sin_m > hmax_m + 1e-3:
                out[bi - bi0, bj - bj0] = 1
    return out


@njit(cache=True, nogil=True)
def extent(rows, cols):
    """``(min(rows), max(rows), min(cols), max(cols))`` of non-empty index lists, in one pass."""
    r0 = r1 = np.int64(rows[0])
    c0 = c1 = np.int64(cols[0])
    for o in range(1, rows.shape[0]):
        r, c = np.int64(rows[o]), np.int64(cols[o])
        r0, r1, c0, c1 = min(r0, r), max(r1, r), min(c0, c), max(c1, c)
    return r0, r1, c0, c1
