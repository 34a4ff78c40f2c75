r"""Surface geometry on the Moon: body-fixed points, DEM normals, illumination angles.

Frame: Moon-centred body-fixed, km.  A DEM pixel at planetocentric longitude
:math:`\lambda`, latitude :math:`\phi` (degrees) and height :math:`h` (metres above
the 1737.4 km sphere) is the point

.. math:: \mathbf{p} = (R + h/1000)(\cos\phi\cos\lambda, \cos\phi\sin\lambda, \sin\phi).

Normals come from the 3-D points of neighbouring DEM pixels (central differences),
so they are correct at any latitude, and :math:`\cos i = \mathbf{n}\cdot\mathbf{l}`,
:math:`\cos e = \mathbf{n}\cdot\mathbf{v}` (seed 001 eqs. 4-5) with unit vectors to
the Sun and to the spacecraft.
"""
from __future__ import annotations

import numpy as np

from ..constants import MOON_RADIUS_KM, MOON_RADIUS_M

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


#: How :func:`illumination` sums the three products of a dot product: ``"einsum"`` (the
#: solver and the forward models) or ``"sum"`` (``np.sum`` over the last axis, x + y + z
#: left to right: the legacy mode's numerics, which differ from einsum's in the last bit).
SUMMATIONS = ("einsum", "sum")


def _dot(a, b, summation: str = "einsum"):
    """Row-wise dot product of ``(..., 3)`` arrays, summed as ``summation`` says (see :data:`SUMMATIONS`)."""
    if summation == "einsum":
        return np.einsum("...i,...i->...", a, b)
    if summation == "sum":
        return np.sum(a * b, axis=-1)
    raise ValueError(f"summation must be one of {', '.join(SUMMATIONS)}, got {summation!r}")


def _unit(v, summation: str = "einsum"):
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / np.sqrt(_dot(v, v, summation))[..., None]


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


def illumination(points_km, normals, sun_km, spacecraft_km, summation: str = "einsum"):
    r"""``(cos i, cos e, alpha)`` per pixel; alpha (phase angle) in radians (seed 001 eqs. 4-5).

    :math:`\cos i = \mathbf{n}\cdot\mathbf{l}`, :math:`\cos e = \mathbf{n}\cdot\mathbf{v}`,
    :math:`\cos\alpha = \mathbf{l}\cdot\mathbf{v}` with unit vectors from the points to
    the Sun and the spacecraft.  ``sun_km`` and ``spacecraft_km`` are body-fixed positions
    of one image, in the unit of ``points_km`` (km here; the legacy mode passes metres).
    ``summation="sum"`` sums the dot products (and the norms) as the legacy mode did
    (:data:`SUMMATIONS`); the default keeps the solver's numerics.
    """
    l = _unit(np.asarray(sun_km, dtype=np.float64) - points_km, summation)
    v = _unit(np.asarray(spacecraft_km, dtype=np.float64) - points_km, summation)
    return (_dot(normals, l, summation), _dot(normals, v, summation),
            np.arccos(np.clip(_dot(l, v, summation), -1.0, 1.0)))


def merge_dem_layers(layers, shape) -> np.ndarray:
    """Heights where DEMs overlap: the mean of the DEMs with a value there (seed 000 section 6).

    The one overlap rule of the package, used by ``ingest`` (:class:`lunaralbedo.ingest.dem.DemMosaic`)
    and ``solve`` (:func:`lunaralbedo.io.rasters.read_dem_onto_grid`): "if the DEM images
    overlap, the values from all images at a given pixel will be averaged".  ``layers``
    yields one array of ``shape`` per DEM (metres, NaN = no value), in file order; the
    float64 sum runs in that order, so the result does not depend on anything else.
    Returns float64 metres, NaN where no DEM has a value.
    """
    total = np.zeros(shape, np.float64)
    count = np.zeros(shape, np.int32)
    for layer in layers:
        d = np.asarray(layer)
        ok = np.isfinite(d)
        total[ok] += d[ok]
        count[ok] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def radius_to_height(values_m: np.ndarray, mode: str = "auto") -> tuple[np.ndarray, bool]:
    """Heights (metres above 1737.4 km) from DEM values; ``mode`` is auto, radius or height.

    Returns ``(heights, was_radius)``.  In ``auto`` mode the values are radius when
    their median exceeds :data:`RADIUS_THRESHOLD_M` (1000 km).
    """
    if mode not in ("auto", "radius", "height"):
        raise ValueError(f"mode must be auto, radius or height, got {mode!r}")
    finite = values_m[np.isfinite(values_m)]
    is_radius = mode == "radius" or (mode == "auto" and finite.size and float(np.median(finite)) > RADIUS_THRESHOLD_M)
    return (values_m - MOON_RADIUS_M if is_radius else values_m), bool(is_radius)
