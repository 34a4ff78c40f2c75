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


@njit(cache=True)
def _trig_tables(lon0, dlon, w, lat0, dlat, h):
    """Cosines and sines of the pixel-centre longitudes and latitudes (radians from ``transform * (c + 0.5, r + 0.5)``)."""
    d2r = math.pi / 180.0
    cos_lon, sin_lon, cos_lat, sin_lat = np.empty(w), np.empty(w), np.empty(h), np.empty(h)
    for j in range(w):
        lon = (lon0 + (j + 0.5) * dlon) * d2r
        cos_lon[j], sin_lon[j] = math.cos(lon), math.sin(lon)
    for i in range(h):
        lat = (lat0 + (i + 0.5) * dlat) * d2r
        cos_lat[i], sin_lat[i] = math.cos(lat), math.sin(lat)
    return cos_lon, sin_lon, cos_lat, sin_lat


@njit(cache=True)
def _march_pixels(dem, prm, max_steps, exact, decide, cos_lon, sin_lon, cos_lat, sin_lat, sun, rows, cols,
                  lev_top, lev_slope, lev_off, lev_width, lev_shift, lev_skip, out):
    """The march of every pixel ``(rows[o], cols[o])`` into ``out[o]``: 1 shadowed, 0 lit, 2 (``decide``) not
    answered by the global slope bound (``prm[8]``; 0: none); ``prm[9]``, ``prm[10]``: offsets of rows, columns."""
    lon0, dlon, lat0, dlat, step_km, hmax_m, tol_m, radius, slope = prm[0], prm[1], prm[2], prm[3], prm[4], \
        prm[5], prm[6], prm[7], prm[8]
    roff, coff = int(prm[9]), int(prm[10])
    h_, w_ = dem.shape
    lon_mid = lon0 + dlon * w_ / 2.0
    d2r = math.pi / 180.0
    kx, ky = 1.0 / (d2r * dlon), 1.0 / (d2r * dlat)
    n_lev = lev_shift.shape[0]
    for o in range(rows.shape[0]):
        i, j = roff + np.int64(rows[o]), coff + np.int64(cols[o])
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
                x, y = _sample_xy(qx, qy, qz, cos_lon[j], sin_lon[j], cos_lat[i], sin_lat[i], i, j, kx, ky)
            if x < 0.0 or y < 0.0 or x > w_ - 1 or y > h_ - 1:
                break
            ix, iy = min(int(x), w_ - 2), min(int(y), h_ - 2)
            fx, fy = x - ix, y - iy
            z = ((dem[iy, ix] * (1 - fx) + dem[iy, ix + 1] * fx) * (1 - fy)
                 + (dem[iy + 1, ix] * (1 - fx) + dem[iy + 1, ix + 1] * fx) * fy)
            if np.isfinite(z) and hray < z - tol_m:
                out[o] = 1
                break
