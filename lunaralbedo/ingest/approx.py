"""Image coordinates of a DEM grid by exact projection on a coarse grid plus interpolation.

What GDAL's approximate transformer does for its warper, adapted to a DEM: the
camera model (for a line scanner a per-point search for the exposure line) runs
only on the nodes of a coarse grid (every ``step`` output pixels) at three heights
spanning the block's DEM range; every pixel then gets its cube ``(sample, line)``
by bilinear interpolation between nodes and quadratic (Lagrange) interpolation in
its own height.  The mapping is smooth in (lon, lat, h) — the DEM's roughness
enters only through the pixel's own height — so this is accurate far below a pixel.

The error is *checked*: in every cell the exact projection is evaluated at the
centre pixel and at the cell's highest and lowest pixels; a cell where any check
differs by more than ``max_error_px`` (default 0.125 px, GDAL's default) or where
some nodes are not imaged (the edge of a line scanner's time range, behind the
camera) is projected exactly, pixel by pixel.

Units: lon/lat degrees on a north-up grid (``transform`` maps (col, row) of pixel
corners to degrees), heights metres above the 1737.4 km sphere, body-fixed km.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..model.geometry import body_fixed

STEP = 32
MAX_ERROR_PX = 0.125


def _nodes(n: int, step: int) -> np.ndarray:
    """Node indices ``0, step, ...`` and always ``n - 1``; two nodes at least (the second may lie past the end)."""
    idx = np.arange(0, n, step)
    if idx[-1] != n - 1:
        idx = np.append(idx, n - 1)
    return idx if len(idx) > 1 else np.array([0, 1])


def _lonlat(transform, cols, rows):
    return transform.c + transform.a * (np.asarray(cols) + 0.5), transform.f + transform.e * (np.asarray(rows) + 0.5)


def exact_coordinates(camera, transform, rows, cols, heights):
    """Unclipped cube ``(sample, line)`` of grid pixels ``(rows, cols)`` (global grid indices) at ``heights`` (m)."""
    lon, lat = _lonlat(transform, cols, rows)
    return camera.ground_to_image(body_fixed(lon, lat, heights), clip=False)


@njit(cache=True)
def _cell_of(n, nodes):
    """Cell index (left node) of every pixel 0..n-1 and its fraction between the cell's two nodes."""
    cell = np.empty(n, np.int64)
    frac = np.empty(n, np.float64)
    a = 0
    for i in range(n):
        while a + 2 < len(nodes) and i >= nodes[a + 1]:
            a += 1
        cell[i] = a
        frac[i] = (i - nodes[a]) / (nodes[a + 1] - nodes[a])
    return cell, frac


@njit(cache=True)
def _interpolate(heights, hk, node_s, node_l, rcell, rfrac, ccell, cfrac, out_s, out_l):
    """Bilinear between nodes at each of the 3 heights ``hk``, then Lagrange in the pixel's height."""
    h0, h1, h2 = hk[0], hk[1], hk[2]
    d0, d1, d2 = (h0 - h1) * (h0 - h2), (h1 - h0) * (h1 - h2), (h2 - h0) * (h2 - h1)
    for i in range(heights.shape[0]):
        a, fr = rcell[i], rfrac[i]
        for j in range(heights.shape[1]):
            h = heights[i, j]
            b, fc = ccell[j], cfrac[j]
            w00, w01, w10, w11 = (1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc
            l0 = (h - h1) * (h - h2) / d0
            l1 = (h - h0) * (h - h2) / d1
            l2 = (h - h0) * (h - h1) / d2
            s = 0.0
            li = 0.0
            for k, lk in ((0, l0), (1, l1), (2, l2)):
                s += lk * (w00 * node_s[k, a, b] + w01 * node_s[k, a, b + 1] + w10 * node_s[k, a + 1, b] + w11 * node_s[k, a + 1, b + 1])
                li += lk * (w00 * node_l[k, a, b] + w01 * node_l[k, a, b + 1] + w10 * node_l[k, a + 1, b] + w11 * node_l[k, a + 1, b + 1])
            out_s[i, j] = s
            out_l[i, j] = li


@njit(cache=True)
def _check_points(heights, rcell, ccell, n_rc, n_cc):
    """Per cell, flat pixel indices of its highest and lowest finite pixel (-1 when none)."""
    hi = np.full((n_rc, n_cc), -1, np.int64)
    lo = np.full((n_rc, n_cc), -1, np.int64)
    hmax = np.full((n_rc, n_cc), -np.inf)
    hmin = np.full((n_rc, n_cc), np.inf)
    w = heights.shape[1]
    for i in range(heights.shape[0]):
        a = rcell[i]
        for j in range(w):
            h = heights[i, j]
            if not np.isfinite(h):
                continue
            b = ccell[j]
            if h > hmax[a, b]:
                hmax[a, b] = h
                hi[a, b] = i * w + j
            if h < hmin[a, b]:
                hmin[a, b] = h
                lo[a, b] = i * w + j
    return hi, lo


def image_coordinates(camera, transform, row0: int, heights, step: int = STEP, max_error_px: float = MAX_ERROR_PX):
    """Unclipped cube ``(sample, line)`` (1-based, float64) of a block of grid rows; NaN where not imaged.

    ``heights`` (metres, NaN = no DEM) are the rows ``row0 ...`` of the grid of ``transform``.
    Returns ``(s, l, refined)`` with ``refined`` the fraction of pixels projected exactly.
    """
    heights = np.ascontiguousarray(heights, dtype=np.float64)
    nh, nw = heights.shape
    out_s = np.full((nh, nw), np.nan)
    out_l = np.full((nh, nw), np.nan)
    finite = np.isfinite(heights)
    if not finite.any():
        return out_s, out_l, 0.0
    hmin, hmax = float(heights[finite].min()), float(heights[finite].max())
    if hmax - hmin < 2.0:
        hmin, hmax = hmin - 1.0, hmax + 1.0
    hk = np.array([hmin, 0.5 * (hmin + hmax), hmax])
    rn, cn = _nodes(nh, step), _nodes(nw, step)
    rr, cc = np.meshgrid(row0 + rn, cn, indexing="ij")
    ns, nl = exact_coordinates(camera, transform, rr[None], cc[None], hk[:, None, None] * np.ones((3, *rr.shape)))
    rcell, rfrac = _cell_of(nh, rn)
    ccell, cfrac = _cell_of(nw, cn)
    _interpolate(heights, hk, np.ascontiguousarray(ns), np.ascontiguousarray(nl), rcell, rfrac, ccell, cfrac, out_s, out_l)
    node_bad = np.any(~np.isfinite(ns) | ~np.isfinite(nl), axis=0)
    corners = np.stack([node_bad[:-1, :-1], node_bad[:-1, 1:], node_bad[1:, :-1], node_bad[1:, 1:]])
    n_rc, n_cc = len(rn) - 1, len(cn) - 1
    bad = corners.any(axis=0) & ~corners.all(axis=0)
    # checks: the centre pixel and the highest and lowest pixel of every cell
    mid_r = np.minimum((rn[:-1] + rn[1:]) // 2, nh - 1)
    mid_c = np.minimum((cn[:-1] + cn[1:]) // 2, nw - 1)
    hi, lo = _check_points(heights, rcell, ccell, n_rc, n_cc)
    centre = (mid_r[:, None] * nw + mid_c[None, :]).ravel()
    cells = np.concatenate([np.arange(n_rc * n_cc)] * 3)
    flat = np.concatenate([centre, hi.ravel(), lo.ravel()])
    ok = flat >= 0
    cells, flat = cells[ok], flat[ok]
    ci, cj = np.divmod(flat, nw)
    es, el = exact_coordinates(camera, transform, row0 + ci, cj, heights.ravel()[flat])
    err = np.hypot(out_s.ravel()[flat] - es, out_l.ravel()[flat] - el)
    fail = ~(err <= max_error_px) & (np.isfinite(es) | np.isfinite(out_s.ravel()[flat]))
    bad.ravel()[cells[fail]] = True
    pix = bad[rcell[:, None], ccell[None, :]] & finite
    refined = float(np.count_nonzero(pix)) / pix.size
    if refined:
        pi, pj = np.nonzero(pix)
        out_s[pi, pj], out_l[pi, pj] = exact_coordinates(camera, transform, row0 + pi, pj, heights[pi, pj])
    return out_s, out_l, refined
