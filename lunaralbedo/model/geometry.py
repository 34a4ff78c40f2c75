r"""Surface geometry on the Moon: body-fixed points, DEM normals, illumination angles.

Frame: Moon-centred body-fixed, km.  A DEM pixel at planetocentric longitude
:math:`\lambda`, latitude :math:`\phi` (degrees) and height :math:`h` (metres above
the 1737.4 km sphere) is the point

.. math:: \mathbf{p} = (R + h/1000)(\cos\phi\cos\lambda, \cos\phi\sin\lambda, \sin\phi).

Normals come from the 3-D points of neighbouring DEM pixels (central differences),
so they are correct at any latitude, and :math:`\cos i = \mathbf{n}\cdot\mathbf{l}`,
:math:`\cos e = \mathbf{n}\cdot\mathbf{v}` (Nefian et al. (LPSC), eqs. 4-5) with unit vectors to
the Sun and to the spacecraft; the phase angle is :math:`\alpha = \arccos(\mathbf{l}\cdot\mathbf{v})`
(:func:`.vacos.acos`, within 1 ulp of libm's, but one that loops can vectorise).

The solver's prepare step uses the numba kernels at the end of this module
(:func:`surface_block`, :func:`observe_window`): :func:`surface_block` gives the bytes of
:func:`body_fixed` and :func:`dem_normals` (the same operations in the same order, planes
x, y, z instead of a last axis of 3), and :func:`observe_window` those of
:func:`illumination`; both run the one per-pixel kernel :func:`_cosines_at`
(``tests/test_prepare_kernels.py``).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..constants import MOON_RADIUS_KM, MOON_RADIUS_M
from . import vacos

#: Radius values (metres) above this are taken as radius, not height.
RADIUS_THRESHOLD_M = 1.0e6


def lonlat_grid(transform, shape):
    """Longitude and latitude (degrees) of the pixel centres of a north-up grid."""
    h, w = shape
    cols = np.arange(w) + 0.5
    rows = np.arange(h) + 0.5
    lon = transform.c + transform.a * cols
    lat = transform.f + transform.e * rows
    return np.broadcast_to(lon[None, :], shape), np.broadcast_to(lat[:, None], shape)


def body_fixed(lon_deg, lat_deg, height_m, unit: str = "km"):
    """Body-fixed points, shape ``(..., 3)``, from lon/lat (degrees) and height (metres).

    In km by default; ``unit="m"`` gives metres (:math:`R + h` with R = 1737400 m),
    the numerics of the legacy mode.
    """
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    if unit == "km":
        r = MOON_RADIUS_KM + np.asarray(height_m, dtype=np.float64) / 1000.0
    elif unit == "m":
        r = MOON_RADIUS_M + np.asarray(height_m, dtype=np.float64)
    else:
        raise ValueError(f"unit must be km or m, got {unit!r}")
    cl = np.cos(lat)
    return np.stack([r * cl * np.cos(lon), r * cl * np.sin(lon), r * np.sin(lat)], axis=-1)


def lonlat_height(points_km):
    """Inverse of :func:`body_fixed`: (lon deg, lat deg, height m) of ``(..., 3)`` points in km."""
    p = np.asarray(points_km, dtype=np.float64)
    r = np.linalg.norm(p, axis=-1)
    lon = np.degrees(np.arctan2(p[..., 1], p[..., 0]))
    lat = np.degrees(np.arcsin(np.clip(p[..., 2] / r, -1, 1)))
    return lon, lat, (r - MOON_RADIUS_KM) * 1000.0


def _central_difference(a, axis):
    """``np.gradient`` along ``axis`` of a 2-D array (central inside, one-sided at the edges)."""
    g = np.empty_like(a)
    a, g = (a, g) if axis == 0 else (a.T, g.T)
    g[1:-1] = (a[2:] - a[:-2]) * 0.5
    g[0] = a[1] - a[0]
    g[-1] = a[-1] - a[-2]
    return g if axis == 0 else g.T


def _backward_difference(a, axis):
    """``a[i] - a[i-1]`` along ``axis`` of a 2-D array; NaN in the first row (column)."""
    g = np.full_like(a, np.nan)
    a, g = (a, g) if axis == 0 else (a.T, g.T)
    g[1:] = a[1:] - a[:-1]
    return g if axis == 0 else g.T


def dem_normals(points_km, differences: str = "central"):
    """Outward unit normals of a grid of body-fixed points ``(H, W, 3)``.

    The normal is (towards south) x (towards east) of the neighbouring points, flipped
    to point away from the Moon's centre.  ``differences="central"`` (the solver):
    central differences, one-sided at the edges.  ``differences="backward"`` (the
    legacy mode): ``p - p_up`` and ``p - p_left``, so the first row and column have
    no normal (NaN).  Pixels next to NaN heights are NaN.  Any length unit.
    """
    p = np.asarray(points_km, dtype=np.float64)
    diff = {"central": _central_difference, "backward": _backward_difference}.get(differences)
    if diff is None:
        raise ValueError(f"differences must be central or backward, got {differences!r}")
    x, y, z = (np.ascontiguousarray(p[..., i]) for i in range(3))
    rx, ry, rz = (diff(c, 0) for c in (x, y, z))  # towards south (increasing row)
    cx, cy, cz = (diff(c, 1) for c in (x, y, z))  # towards east (increasing column)
    nx, ny, nz = ry * cz - rz * cy, rz * cx - rx * cz, rx * cy - ry * cx
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    norm = np.where(nx * x + ny * y + nz * z < 0, -norm, norm)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.stack([nx / norm, ny / norm, nz / norm], axis=-1)


def illumination(points_km, normals, sun_km, spacecraft_km):
    r"""``(cos i, cos e, alpha)`` per pixel; alpha (phase angle) in radians (Nefian et al. (LPSC), eqs. 4-5).

    :math:`\cos i = \mathbf{n}\cdot\mathbf{l}`, :math:`\cos e = \mathbf{n}\cdot\mathbf{v}`,
    :math:`\cos\alpha = \mathbf{l}\cdot\mathbf{v}` with unit vectors from the points to
    the Sun and the spacecraft.  ``sun_km`` and ``spacecraft_km`` are body-fixed positions
    of one image, in the unit of ``points_km`` (km here; the legacy mode passes metres).
    Runs :func:`_illumination_at`, the per-point kernel the solver's prepare step also uses;
    its sums run left to right (x, y, z), the legacy mode's order.
    """
    p = np.asarray(points_km, dtype=np.float64)
    n = np.broadcast_to(np.asarray(normals, dtype=np.float64), p.shape)
    shape = p.shape[:-1]
    ci, ce, al = _illumination_flat(np.ascontiguousarray(p.reshape(-1, 3)), np.ascontiguousarray(n.reshape(-1, 3)),
                                    np.asarray(sun_km, dtype=np.float64), np.asarray(spacecraft_km, dtype=np.float64))
    return ci.reshape(shape), ce.reshape(shape), al.reshape(shape)


@njit(cache=True, error_model="numpy", inline="always")
def _cosines_at(px, py, pz, nx, ny, nz, sx, sy, sz, vx, vy, vz):
    r"""Nefian et al. (LPSC), eqs. 4-5 at one point ``p`` with normal ``n``, Sun ``s``, spacecraft ``v`` (body-fixed):
    :math:`\cos i = \mathbf{n}\cdot\mathbf{l}`, :math:`\cos e = \mathbf{n}\cdot\mathbf{v}` and
    :math:`\cos\alpha = \mathbf{l}\cdot\mathbf{v}` (clipped to [-1, 1]) with unit vectors
    :math:`\mathbf{l}, \mathbf{v}` from the point (each scaled by the reciprocal of its length).
    The one implementation: :func:`_illumination_at` and :func:`observe_window` run it."""
    lx, ly, lz = sx - px, sy - py, sz - pz
    il = 1.0 / math.sqrt(lx * lx + ly * ly + lz * lz)
    lx, ly, lz = lx * il, ly * il, lz * il
    vx, vy, vz = vx - px, vy - py, vz - pz
    iv = 1.0 / math.sqrt(vx * vx + vy * vy + vz * vz)
    vx, vy, vz = vx * iv, vy * iv, vz * iv
    c = min(max(lx * vx + ly * vy + lz * vz, -1.0), 1.0)
    return nx * lx + ny * ly + nz * lz, nx * vx + ny * vy + nz * vz, c


@njit(cache=True, error_model="numpy", inline="always")
def _illumination_at(px, py, pz, nx, ny, nz, sun, sc):
    r"""``(cos i, cos e, alpha)`` at one point: :func:`_cosines_at` and :math:`\alpha = \arccos(\mathbf{l}\cdot\mathbf{v})`
    (:func:`.vacos.acos`)."""
    a, b, c = _cosines_at(px, py, pz, nx, ny, nz, sun[0], sun[1], sun[2], sc[0], sc[1], sc[2])
    return a, b, vacos.acos(c)


@njit(cache=True, nogil=True, error_model="numpy")
def _illumination_flat(p, n, sun, sc):
    m = p.shape[0]
    ci, ce, al = np.empty(m), np.empty(m), np.empty(m)
    for o in range(m):
        ci[o], ce[o], al[o] = _illumination_at(p[o, 0], p[o, 1], p[o, 2], n[o, 0], n[o, 1], n[o, 2], sun, sc)
    return ci, ce, al


def merge_dem_layers(layers, shape, dtype=np.float64, owned: bool = False) -> np.ndarray:
    """Heights where DEMs overlap: the mean of the DEMs with a value there (the PhotometryTK manual, section 6).

    The one overlap rule of the package, used by ``ingest`` (:class:`lunaralbedo.ingest.dem.DemMosaic`)
    and ``solve`` (:func:`lunaralbedo.io.rasters.read_dem_onto_grid`): "if the DEM images
    overlap, the values from all images at a given pixel will be averaged".  ``layers``
    yields one array of ``shape`` per DEM (metres, NaN = no value), in file order; the
    float64 sum runs in that order, so the result does not depend on anything else.
    Returns metres of ``dtype`` (the float64 mean rounded once), NaN where no DEM has a value;
    one DEM gives its own values (``0.0 + h``: -0.0 becomes 0.0), formed in ``dtype`` directly
    when its values are of that type (float32 heights: the same bytes, no float64 pass).
    ``owned``: the layers are the caller's to overwrite (fresh reads): one DEM's array of that
    type and shape is then returned itself, its -0.0 made 0.0 in place.
    """
    layers = iter(layers)
    first = next(layers, None)
    if first is None:
        return np.full(shape, np.nan, dtype)
    second = next(layers, None)
    if second is None:  # one DEM: its values (the sum's 0.0 + h turns -0.0 into 0.0; NaN stays NaN)
        first = np.asarray(first)
        work = dtype if first.dtype == np.dtype(dtype) else np.float64
        if owned and first.dtype == np.dtype(work) and first.shape == tuple(shape) and first.flags.writeable:
            out = first
        else:
            out = np.array(np.broadcast_to(first.astype(work, copy=False), shape))
        out += work(0.0)
        return out.astype(dtype, copy=False)
    total = np.zeros(shape, np.float64)
    count = np.zeros(shape, np.int32)
    for d in (first, second, *layers):
        d = np.asarray(d)
        ok = np.isfinite(d)
        total += np.where(ok, d, 0.0)  # total is never -0.0, so adding 0.0 where there is no value changes nothing
        count += ok
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan).astype(dtype, copy=False)


def radius_to_height(values_m: np.ndarray, mode: str = "auto") -> tuple[np.ndarray, bool]:
    """Heights (metres above 1737.4 km) from DEM values; ``mode`` is auto, radius or height.

    Returns ``(heights, was_radius)``.  In ``auto`` mode the values are radius when
    their median exceeds :data:`RADIUS_THRESHOLD_M` (1000 km).
    """
    if mode not in ("auto", "radius", "height"):
        raise ValueError(f"mode must be auto, radius or height, got {mode!r}")
    is_radius = mode == "radius" or (mode == "auto" and _median_exceeds(values_m, RADIUS_THRESHOLD_M))
    return (values_m - MOON_RADIUS_M if is_radius else values_m), bool(is_radius)


def _median_exceeds(values, threshold: float) -> bool:
    """``median(finite values) > threshold`` (False when none), by counting (one numba pass): no sort unless the two
    middle values straddle the threshold."""
    values = np.asarray(values)
    if values.dtype.kind != "f":
        values = values.astype(np.float64)
    n, above = _count_finite_above(np.ascontiguousarray(values).ravel(), values.dtype.type(threshold))
    if n == 0:
        return False
    if above >= n // 2 + 1:  # the middle value(s) all above
        return True
    if above <= (n - 1) // 2:  # the middle value(s) all at or below
        return False
    return float(np.median(values[np.isfinite(values)])) > threshold


@njit(cache=True, nogil=True)
def _count_finite_above(values, threshold):
    """How many ``values`` are finite, and how many of those exceed ``threshold`` (of their type, as NumPy 2 compares
    an array with a Python float)."""
    n = 0
    above = 0
    for v in values:
        if np.isfinite(v):
            n += 1
            above += v > threshold
    return n, above


# --------------------------------------------------------------------------- kernels of the solver's prepare step
def lonlat_axes(transform, shape):
    """Longitude of every column and latitude of every row (degrees) of a north-up grid (see :func:`lonlat_grid`)."""
    h, w = shape
    return transform.c + transform.a * (np.arange(w) + 0.5), transform.f + transform.e * (np.arange(h) + 0.5)


@njit(cache=True, error_model="numpy", inline="always")
def _point_at(h, radius_km, cl, sl, cj, sj):
    """Body-fixed point (km) of height ``h`` (m; NaN counts as 0, as :func:`body_fixed` of ``nan_to_num``
    heights) at the latitude and longitude of cosines/sines ``cl, sl`` and ``cj, sj``."""
    h = np.float64(h)
    h = 0.0 if h != h else h
    r = radius_km + h / 1000.0
    rc = r * cl
    return rc * cj, rc * sj, r * sl


@njit(cache=True, error_model="numpy", inline="always")
def _normal_at(x, y, z, xs, ys, zs, xn, yn, zn, xe, ye, ze, xw, yw, zw):
    """Outward unit normal at point ``(x, y, z)`` from its south, north, east and west neighbours (central
    differences: (towards south) x (towards east), as :func:`dem_normals`)."""
    rx, ry, rz = (xs - xn) * 0.5, (ys - yn) * 0.5, (zs - zn) * 0.5
    cx, cy, cz = (xe - xw) * 0.5, (ye - yw) * 0.5, (ze - zw) * 0.5
    nx, ny, nz = ry * cz - rz * cy, rz * cx - rx * cz, rx * cy - ry * cx
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    norm = -norm if nx * x + ny * y + nz * z < 0 else norm
    return nx / norm, ny / norm, nz / norm


@njit(cache=True, nogil=True, error_model="numpy")
def surface_block(coslon, sinlon, coslat, sinlat, height_m, radius_km):
    """Points (km) of a DEM block with a one-pixel halo, and the normals of its inner pixels, coordinate-major.

    ``height_m`` ``(H+2, W+2)`` (NaN counts as 0, as :func:`body_fixed` of ``nan_to_num``
    heights), trigonometric values of each column's longitude and each row's latitude.
    Returns points ``(3, H+2, W+2)`` and normals ``(3, H, W)`` (x, y, z planes;
    ``np.moveaxis(a, 0, -1)`` gives the ``(..., 3)`` layout of :func:`body_fixed` and
    :func:`dem_normals` (central differences), whose bytes they are: the same operations in
    the same order, :func:`_point_at` and :func:`_normal_at`, which :func:`observe_window` runs too).
    """
    hh, ww = height_m.shape
    pts = np.empty((3, hh, ww))
    for i in range(hh):
        for j in range(ww):
            pts[0, i, j], pts[1, i, j], pts[2, i, j] = _point_at(height_m[i, j], radius_km, coslat[i], sinlat[i],
                                                                 coslon[j], sinlon[j])
    nrm = np.empty((3, hh - 2, ww - 2))
    x, y, z = pts[0], pts[1], pts[2]
    for i in range(1, hh - 1):
        for j in range(1, ww - 1):
            nrm[0, i - 1, j - 1], nrm[1, i - 1, j - 1], nrm[2, i - 1, j - 1] = _normal_at(
                x[i, j], y[i, j], z[i, j], x[i + 1, j], y[i + 1, j], z[i + 1, j], x[i - 1, j], y[i - 1, j], z[i - 1, j],
                x[i, j + 1], y[i, j + 1], z[i, j + 1], x[i, j - 1], y[i, j - 1], z[i, j - 1])
    return pts, nrm


@njit(cache=True, nogil=True, error_model="numpy")
def observe_window(use, halo_m, coslon, sinlon, coslat, sinlat, radius_km, r_off, c_off, sun, sc, min_cos_i):
    """Candidate observations of one image window: pixels ``use`` with a DEM, cos i >= ``min_cos_i``, cos e > 0.

    ``use`` ``(h, w)`` bool over the window; ``halo_m`` ``(H+2, W+2)`` the heights (m) of the
    block with a one-pixel halo, and the cosines and sines of its columns' longitudes and rows'
    latitudes (as :func:`surface_block`): window pixel ``(r, c)`` is inner block pixel ``(r +
    r_off, c + c_off)``.  Returns window rows and columns (int64) and ``cos i``, ``cos e``,
    ``alpha`` (float64) of the candidates, in row-major order: the values of
    :func:`_illumination_at` at the points and normals of :func:`surface_block`.  The points
    and normals are computed here row by row from the heights (a ring of three rows of
    points) instead of read from the block's arrays: 4 bytes per pixel to read instead of 52.
    Each row's cosines are computed in one vectorised loop, the candidates then copied out,
    and their phase angles taken in one vectorised loop at the end.
    """
    h, w = use.shape
    n = 0
    for r in range(h):
        for c in range(w):
            n += use[r, c]
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    ci, ce, al = np.empty(n), np.empty(n), np.empty(n)
    row_ci, row_ce, row_ca = np.empty(w), np.empty(w), np.empty(w)
    pts = np.empty((3, 3, w + 2))  # a ring of three rows of points (x, y, z; the window's columns and halo)
    nx, ny, nz = np.empty(w), np.empty(w), np.empty(w)
    sx, sy, sz, vx, vy, vz = sun[0], sun[1], sun[2], sc[0], sc[1], sc[2]
    m = 0
    for r in range(h):
        i = r + r_off  # inner block row; halo rows i, i + 1, i + 2 are north, at, south
        for k in range(0 if r == 0 else 2, 3):  # the rows not yet in the ring
            q, cl, sl = (r + k) % 3, coslat[i + k], sinlat[i + k]
            for j in range(w + 2):
                pts[q, 0, j], pts[q, 1, j], pts[q, 2, j] = _point_at(halo_m[i + k, c_off + j], radius_km, cl, sl,
                                                                     coslon[c_off + j], sinlon[c_off + j])
        pn, pa, ps = pts[r % 3], pts[(r + 1) % 3], pts[(r + 2) % 3]
        for c in range(w):
            nx[c], ny[c], nz[c] = _normal_at(pa[0, c + 1], pa[1, c + 1], pa[2, c + 1], ps[0, c + 1], ps[1, c + 1],
                                             ps[2, c + 1], pn[0, c + 1], pn[1, c + 1], pn[2, c + 1],
                                             pa[0, c + 2], pa[1, c + 2], pa[2, c + 2], pa[0, c], pa[1, c], pa[2, c])
        for c in range(w):
            row_ci[c], row_ce[c], row_ca[c] = _cosines_at(pa[0, c + 1], pa[1, c + 1], pa[2, c + 1],
                                                          nx[c], ny[c], nz[c], sx, sy, sz, vx, vy, vz)
        for c in range(w):
            if use[r, c] and np.isfinite(halo_m[i + 1, c_off + c + 1]) and row_ci[c] >= min_cos_i and row_ce[c] > 0:
                rows[m], cols[m], ci[m], ce[m], al[m] = r, c, row_ci[c], row_ce[c], row_ca[c]
                m += 1
    for o in range(m):
        al[o] = vacos.acos(al[o])
    return rows[:m], cols[:m], ci[:m], ce[:m], al[:m]
