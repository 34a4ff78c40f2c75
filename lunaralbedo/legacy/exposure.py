"""Legacy exposure initialisation (reconstruct --init-exposure, actOnImage), pure math.

For one DRG: over every tile it overlaps (skipping tiles where none of its
pixels has a non-zero weight), over the DRG pixels whose centres fall inside
the *unpadded* tile, average the reflectance interpolated (bilinear, float32)
from the tile's DEM grid where all four neighbours have a non-zero
reflectance and the DRG pixel is valid and not below the shadow threshold.
The exposure is ``TR_CONST / mean(R)`` in float32 (``model.exposure_init.seed_exposure``).
"""
from __future__ import annotations

import math

import numpy as np

from .interp import bilinear_f32
from .reflect import reflectance
from .tilesolve import Image, Params, seq_sum, shadow_threshold
from .vwgeo import Geo, boxes_overlap
from .weights import line_weights


def _pixel_range(img_geo: Geo, inner) -> tuple[int, int, int, int]:
    min_x, max_x, min_y, max_y = inner
    bc, br = float(img_geo.col(min_x)), float(img_geo.row(max_y))
    ec, er = float(img_geo.col(max_x)), float(img_geo.row(min_y))
    r0, r1 = max(0, math.floor(br)), min(img_geo.height, math.ceil(er))
    c0, c1 = max(0, math.floor(bc)), min(img_geo.width, math.ceil(ec))
    return r0, r1, c0, c1


def reflectance_sum(img: Image, tiles, p: Params, initial_exposure: float = 1.0) -> tuple[float, int]:
    """``(sum of R, number of pixels)`` of one image over the overlapping tiles (legacy order, float64).

    The exposure is then :func:`lunaralbedo.model.exposure_init.seed_exposure` in float32.

    ``tiles`` yields ``(tile_geo, inner, surface)`` in the tile-list order, where
    ``surface`` = ``(points, normals)`` of the tile's DEM.
    """
    total, count = 0.0, 0
    for tile_geo, inner, surf in tiles:
        if not boxes_overlap(tile_geo.corners(), img.corners):
            continue
        r0, r1, c0, c1 = _pixel_range(img.geo, inner)
        if r0 >= r1 or c0 >= c1:
            continue
        rr, cc = np.mgrid[r0:r1, c0:c1]
        if p.use_weights and not np.any(line_weights(img.lines, cc, rr) != 0):
            continue
        R, _ = reflectance(p.kind, surf[0], surf[1], img.sun_km, img.sc_km, p.c1, p.c2)
        lon, lat = img.geo.lon(cc), img.geo.lat(rr)
        min_x, max_x, min_y, max_y = inner
        m = (min_x <= lon) & (lon < max_x) & (min_y <= lat) & (lat < max_y)
        x, y = tile_geo.col(lon), tile_geo.row(lat)
        h, w = R.shape
        m &= (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        xs, ys = np.clip(x, 0, w - 1), np.clip(y, 0, h - 1)
        j0, j1 = np.floor(xs).astype(int), np.ceil(xs).astype(int)
        i0, i1 = np.floor(ys).astype(int), np.ceil(ys).astype(int)
        m &= (R[i0, j0] != 0) & (R[i1, j0] != 0) & (R[i0, j1] != 0) & (R[i1, j1] != 0)
        if not np.any(m):
            continue
        Ri = bilinear_f32(R, x[m], y[m]).astype(np.float64)
        t = shadow_threshold(p, (Ri * initial_exposure).astype(np.float32)).astype(np.float64)
        vals, ok = img.values[rr[m], cc[m]], img.valid[rr[m], cc[m]]
        keep = ok & (vals >= t)
        Rk = Ri[keep]
        total = seq_sum(total, Rk)
        count += int(Rk.size)
    return total, count
