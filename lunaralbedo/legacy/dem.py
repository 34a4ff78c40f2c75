"""The legacy mean-DEM tile (reconstruct --init-dem), as pure array math.

For one padded tile the legacy program

1. merged the overlapping DEM tiles onto the pixel grid of the first of them,
   over the tile's extent plus a 2-pixel margin (values landing on the same
   merged pixel are averaged; nodata pixels are skipped);
2. sampled that merged DEM at every tile pixel centre with *bicubic*
   interpolation, but only where the four bilinear neighbours are all valid
   (the two outer rows/columns of the bicubic stencil are not checked);
3. wrote the result as float32 with the DEM's nodata value elsewhere.
"""
from __future__ import annotations

import math

import numpy as np

from .interp import bicubic_f32
from .vwgeo import Geo, sub_window

MARGIN = 2


def merge_dems(dems: list[tuple[np.ndarray, Geo]], nodata: float, nw, se) -> tuple[np.ndarray, Geo] | None:
    """Merge the parts of ``dems`` around the box ``nw``..``se`` (lon/lat of pixel centres).

    Returns the merged float32 DEM (nodata where no input) and its georeference,
    or None when no DEM reaches the box.
    """
    nd = np.float32(nodata)
    merged = count = mgeo = None
    for data, geo in dems:
        win = sub_window(geo, nw, se, MARGIN)
        if win is None:
            continue
        c0, r0, c1, r1 = win
        sub = data[r0:r1, c0:c1]
        sgeo = geo.window(c0, r0, c1 - c0, r1 - r0)
        if merged is None:
            bc, br = float(sgeo.col(nw[0])), float(sgeo.row(nw[1]))
            ec, er = float(sgeo.col(se[0])), float(sgeo.row(se[1]))
            b0, b1 = math.floor(bc) - MARGIN, math.floor(br) - MARGIN
            e0, e1 = math.ceil(ec) + MARGIN, math.ceil(er) + MARGIN
            ncols, nrows = int(round(e0 - b0)), int(round(e1 - b1))
            merged = np.full((nrows, ncols), nd, dtype=np.float32)
            count = np.zeros((nrows, ncols), dtype=np.int32)
            mgeo = sgeo.window(b0, b1, ncols, nrows)
        rows, cols = np.mgrid[0 : sub.shape[0], 0 : sub.shape[1]]
        lc = np.rint(mgeo.col(sgeo.lon(cols))).astype(np.int64)  # C round: no exact halves on a common grid
        lr = np.rint(mgeo.row(sgeo.lat(rows))).astype(np.int64)
        ok = (lc >= 0) & (lc < merged.shape[1]) & (lr >= 0) & (lr < merged.shape[0]) & (sub != nd)
        lr, lc, vals = lr[ok], lc[ok], sub[ok]
        first = count[lr, lc] == 0
        merged[lr[first], lc[first]] = vals[first]
        np.add.at(merged, (lr[~first], lc[~first]), vals[~first])
        np.add.at(count, (lr, lc), 1)
    if merged is None:
        return None
    many = count > 1
    merged[many] = (merged[many] / count[many]).astype(np.float32)
    return merged, mgeo


def mean_dem_tile(tile_geo: Geo, dems: list[tuple[np.ndarray, Geo]], nodata: float) -> np.ndarray:
    """The legacy DEM tile on ``tile_geo`` (float32, ``nodata`` where undefined)."""
    nd = np.float32(nodata)
    out = np.full((tile_geo.height, tile_geo.width), nd, dtype=np.float32)
    nw = (float(tile_geo.lon(0)), float(tile_geo.lat(0)))
    se = (float(tile_geo.lon(tile_geo.width - 1)), float(tile_geo.lat(tile_geo.height - 1)))
    res = merge_dems(dems, nodata, nw, se)
    if res is None:
        return out
    merged, mgeo = res
    h, w = merged.shape
    rows, cols = np.mgrid[0 : tile_geo.height, 0 : tile_geo.width]
    x = mgeo.col(tile_geo.lon(cols)).astype(np.float32).astype(np.float64)
    y = mgeo.row(tile_geo.lat(rows)).astype(np.float32).astype(np.float64)
    inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
    xf, xc = np.floor(x).astype(np.int64), np.ceil(x).astype(np.int64)
    yf, yc = np.floor(y).astype(np.int64), np.ceil(y).astype(np.int64)
    xf, xc, yf, yc = (np.clip(v, 0, m - 1) for v, m in ((xf, w), (xc, w), (yf, h), (yc, h)))
    good = inside & (merged[yf, xf] != nd) & (merged[yc, xf] != nd) & (merged[yf, xc] != nd) & (merged[yc, xc] != nd)
    out[good] = bicubic_f32(merged, x[good], y[good])
    return out
