"""One legacy pass over one padded tile (reconstruct's actOnTile), vectorised over pixels.

Modes (one per pass, as reconstruct.sh ran them): ``weights_sum``, ``init``
(eq. 3), ``update`` (eq. 6), ``phase`` (per-tile parts of eq. 5) and ``errors``
(eq. 7).  Images are visited in the image-list order and every per-pixel
accumulator is float32, rounded after each image, like the legacy float
images; the cost function and phase sums are float64 in the legacy order.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..model import updates
from ..model.photometry import lunar_lambert
from .interp import bilinear_f32
from .reflect import reflectance
from .vwgeo import Geo, boxes_overlap, sub_window
from .weights import CenterLines, line_weights

MODES = ("weights_sum", "init", "update", "phase", "errors")


@dataclass
class Image:
    """One selected DRG with what the passes need (pixels, georeference, weights, positions)."""

    key: str
    path: str
    geo: Geo
    values: np.ndarray
    valid: np.ndarray
    lines: CenterLines
    sun_km: np.ndarray | None = None
    sc_km: np.ndarray | None = None

    @property
    def corners(self):
        return self.geo.corners()


@dataclass(frozen=True)
class Params:
    """The settings a pass depends on (legacy float32 values where the legacy kept floats)."""

    kind: int  # 0 mosaic, 1 Lambert, 2 Lunar-Lambert (after the forceMosaic rewrite)
    force_mosaic: bool
    shadow_type: int
    shadow_thresh: float
    tr_const: float
    c1: float
    c2: float
    use_weights: bool
    normalized: bool
    tile_size: float


@dataclass
class TileResult:
    value: np.ndarray | None = None  # float32 albedo/weightsSum/error on the padded grid
    valid: np.ndarray | None = None
    error: np.ndarray | None = None
    error_valid: np.ndarray | None = None
    cost: float = 0.0
    phase: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    extra: dict = field(default_factory=dict)


def shadow_threshold(p: Params, exposure_refl: np.ndarray) -> np.ndarray:
    """Legacy getShadowThresh (float32)."""
    if p.shadow_type == 1:
        return np.full(np.shape(exposure_refl), np.float32(p.shadow_thresh))
    if p.shadow_type in (2, 3):
        with np.errstate(divide="ignore"):
            return (np.float32(p.shadow_thresh) / np.asarray(exposure_refl, dtype=np.float32)).astype(np.float32)
    return np.full(np.shape(exposure_refl), np.float32(-1.0))


def seq_sum(start: float, terms: np.ndarray) -> float:
    """``start + t0 + t1 + ...`` summed left to right in float64 (the legacy loop order)."""
    if terms.size == 0:
        return start
    return float(np.cumsum(np.concatenate([[start], terms.ravel()]))[-1])


def sub_image_window(img_geo: Geo, tile_geo: Geo) -> tuple[int, int, int, int] | None:
    """Legacy getSubImageWithMargin of an image around a tile: ``(col0, row0, col1, row1)``."""
    nw = (float(tile_geo.lon(0)), float(tile_geo.lat(0)))
    se = (float(tile_geo.lon(tile_geo.width - 1)), float(tile_geo.lat(tile_geo.height - 1)))
    return sub_window(img_geo, nw, se)


def solve_tile(mode, tile_geo: Geo, inner, images, exposures, p: Params, surface=None, weights_sum=None, albedo_in=None):
    """Run one legacy pass on a padded tile.

    ``inner`` = ``(min_x, max_x, min_y, max_y)`` of the unpadded tile; ``surface``
    = ``(points, normals)`` of the DEM tile (None in mosaic mode);
    ``weights_sum`` the float32 weightsSum tile (normalised cost only);
    ``albedo_in`` = ``(values float32, valid)`` of the albedo read back from
    its uint8 file (update, phase, errors).
    """
    if mode not in MODES:
        raise ValueError(f"unknown legacy tile mode {mode!r}")
    h, w = tile_geo.height, tile_geo.width
    f32 = np.float32
    acc = np.zeros((h, w), f32)
    norm = np.zeros((h, w), f32)
    touched = np.zeros((h, w), bool)
    err = np.zeros((h, w), f32) if mode == "errors" else None
    cost = 0.0
    pcd = [0.0, 0.0, 0.0, 0.0]
    cols, rows = np.meshgrid(np.arange(w), np.arange(h))
    lon, lat = tile_geo.lon(cols), tile_geo.lat(rows)
    min_x, max_x, min_y, max_y = inner
    in_tile = (min_x <= lon) & (lon < max_x) & (min_y <= lat) & (lat < max_y)
    normalized = p.normalized and mode != "weights_sum"
    tcorners = tile_geo.corners()
    for img in images:
        if not boxes_overlap(img.corners, tcorners):
            continue
        xo, yo = img.geo.col(lon), img.geo.row(lat)
        wgt = line_weights(img.lines, xo, yo).astype(np.float64) if p.use_weights else np.ones((h, w))
        if p.use_weights and not np.any(wgt != 0):
            continue
        win = sub_image_window(img.geo, tile_geo)
        if win is None:
            continue
        c0, r0, c1, r1 = win
        sgeo = img.geo.window(c0, r0, c1 - c0, r1 - r0)
        sval, sok = img.values[r0:r1, c0:c1], img.valid[r0:r1, c0:c1]
        x, y = sgeo.col(lon), sgeo.row(lat)
        m = wgt != 0
        if normalized:
            m &= weights_sum != 0
        sw, sh = c1 - c0, r1 - r0
        m &= (x >= 0) & (x <= sw - 1) & (y >= 0) & (y <= sh - 1)
        xs, ys = np.clip(x, 0, sw - 1), np.clip(y, 0, sh - 1)
        j0, j1 = np.floor(xs).astype(int), np.ceil(xs).astype(int)
        i0, i1 = np.floor(ys).astype(int), np.ceil(ys).astype(int)
        m &= sok[i0, j0] & sok[i1, j0] & sok[i0, j1] & sok[i1, j1]
        touched |= m
        if surface is not None:
            R, alpha = reflectance(p.kind, surface[0], surface[1], img.sun_km, img.sc_km, p.c1, p.c2)
        else:
            R, alpha = np.ones((h, w), f32), np.zeros((h, w), f32)
        R = R.astype(np.float64)
        T = float(f32(exposures.get(img.key, 1.0)))
        if not math.isfinite(T):  # exposure undefined (no usable pixel): the image cannot contribute
            continue
        m &= R != 0.0

        def lit(exposure: float) -> np.ndarray:
            t = shadow_threshold(p, (exposure * R).astype(f32)).astype(np.float64)
            return (sval[i0, j0] >= t) & (sval[i1, j0] >= t) & (sval[i0, j1] >= t) & (sval[i1, j1] >= t)

        lit_t = lit(T)
        if p.force_mosaic:
            # Legacy forceMosaic set the image's exposure to TR_CONST at its first lit pixel, so the
            # adaptive shadow test of every later pixel (row-major) used TR_CONST.
            tr = float(f32(p.tr_const))
            first = np.flatnonzero((m & lit_t).ravel())
            if first.size and p.shadow_type in (2, 3):
                idx = np.arange(h * w).reshape(h, w)
                lit_t = np.where(idx <= first[0], lit_t, lit(tr))
            T = tr
            R = np.ones((h, w))
        m &= lit_t
        eR = T * R
        if not np.any(m):
            continue
        if normalized:
            with np.errstate(divide="ignore", invalid="ignore"):  # pixels with a zero sum are masked out above
                wn = wgt / weights_sum.astype(np.float64)
        else:
            wn = wgt
        pix = bilinear_f32(sval, x[m], y[m]).astype(np.float64)
        ws, er_ = wn[m], eR[m]
        if mode == "weights_sum":
            norm[m] = (norm[m].astype(np.float64) + ws).astype(f32)
            continue
        if mode == "init":  # eq. 3
            num_k, den_k = updates.albedo_terms(pix, er_, ws)
            acc[m] = (acc[m].astype(np.float64) + num_k).astype(f32)
            norm[m] = (norm[m].astype(np.float64) + den_k).astype(f32)
            continue
        a_val, a_ok = albedo_in
        m2 = a_ok[m]
        sel = np.flatnonzero(m.ravel())[m2]
        A = a_val.ravel()[sel].astype(np.float64)
        pix, ws, er_ = pix[m2], ws[m2], er_[m2]
        diff = pix - A * er_  # the residual I - ATR
        inside = in_tile.ravel()[sel]
        if mode == "update":  # eq. 6
            accf, normf = acc.ravel(), norm.ravel()
            num_k, den_k = updates.albedo_terms(diff, er_, ws)
            accf[sel] = (accf[sel].astype(np.float64) + num_k).astype(f32)
            normf[sel] = (normf[sel].astype(np.float64) + den_k).astype(f32)
        elif mode == "phase":  # eq. 5 with dR/dc of eq. 2, G = R / P from the stored R
            al = alpha.ravel()[sel].astype(np.float64)[inside]
            c = (float(f32(p.c1)), float(f32(p.c2)))
            layers = {"alpha": al, "geometric": er_[inside] / lunar_lambert.phase_factor(al, *c)}
            d1, d2 = (A[inside] * d for d in lunar_lambert.derivatives_from(layers, c))
            dd, ww = diff[inside], ws[inside]
            pcd[0] = seq_sum(pcd[0], dd * d1 * ww)
            pcd[1] = seq_sum(pcd[1], d1 * d1 * ww)
            pcd[2] = seq_sum(pcd[2], dd * d2 * ww)
            pcd[3] = seq_sum(pcd[3], d2 * d2 * ww)
        else:  # errors, eq. 7
            errf, normf = err.ravel(), norm.ravel()
            errf[sel] = (errf[sel].astype(np.float64) + updates.error_terms(pix, A, er_, ws)).astype(f32)
            normf[sel] = (normf[sel].astype(np.float64) + ws).astype(f32)
        cost = seq_sum(cost, updates.cost_terms(diff, ws)[inside])  # eq. 1
    res = TileResult(cost=cost, phase=tuple(pcd))
    if mode == "weights_sum":
        res.value = norm
        return res
    if mode == "phase":
        return res
    return _finish(mode, res, acc, norm, touched, err, albedo_in)


def _finish(mode, res, acc, norm, touched, err, albedo_in):
    """The legacy end of actOnTile: validity rules and the division by the normaliser."""
    f32 = np.float32
    if mode == "errors":
        value = albedo_in[0].astype(f32).copy()
        valid = albedo_in[1].copy()
        err_valid = touched & albedo_in[1]
    else:
        value = acc
        valid = touched.copy()
        err_valid = None
        if mode == "update":
            valid &= albedo_in[1]
    valid &= value != 0
    done = valid & (norm != 0)
    if mode == "init":
        value = np.where(done, (value / np.where(done, norm, 1)).astype(f32), value)
    elif mode == "update":
        value = np.where(done, (albedo_in[0].astype(f32) + (value / np.where(done, norm, 1)).astype(f32)).astype(f32), value)
    else:
        err = np.where(done, (err / np.where(done, norm, 1)).astype(f32), err)
    res.value, res.valid = value.astype(f32), valid
    if mode == "errors":
        res.error, res.error_valid = err.astype(f32), err_valid
    return res
