"""Compact observations of one tile: only the pixels where an image has weight.

The former layout held every image's stack over the whole tile, so a narrow strip
(Apollo Metric, NAC) over a 2000 x 2000 px tile was mostly zeros, and every
iteration streamed those zeros from disk.  Here each image is read, and its
geometry computed, only over its own footprint window inside the tile (plus one
pixel), and only observations with positive weight are kept, as 1-D arrays ordered
by image and then by pixel:

* ``pix`` (int32): flat index ``row * width + col`` into the unpadded tile;
* ``image``, ``weight`` and the photometric model's layers (float32);
* ``index`` (global image ids) and ``start`` (offsets: image ``k`` owns
  ``start[k]:start[k+1]``).

Per tile pixel: ``dem`` and ``weights_sum`` (float32) and ``wblend_sum`` (float64,
the denominator of eq. 7).  Memory is ~20-28 bytes per observation plus ~14 bytes
per tile pixel, whatever the tile size and the images' shapes.
"""
from __future__ import annotations

import math

import numpy as np

from ..constants import MIN_COS_INCIDENCE_MODEL
from ..io.rasters import read_dem_onto_grid, read_drg_onto_grid
from ..model import geometry, shadows
from ..model.longitude import overlap_shifts
from .photometry import solver_model
from .scene import Scene
from .terrain import cast_shadow_masks


def image_window(tile, bounds) -> tuple[int, int, int, int] | None:
    """``(r0, r1, c0, c1)`` of the unpadded tile covering lon/lat ``bounds`` plus one pixel; None if empty.

    Longitudes count modulo 360° (a DRG stored at -180..-179 covers a tile at 180..181);
    a DRG meeting the tile on both sides of it gets the window spanning both.
    """
    shifts = overlap_shifts(bounds, tile.padded_bounds) or [0.0]
    west, south, east, north = bounds
    west, east = west + min(shifts), east + max(shifts)
    c0 = max(0, math.floor((west - tile.west) / tile.res_x) - 1)
    c1 = min(tile.width, math.ceil((east - tile.west) / tile.res_x) + 1)
    r0 = max(0, math.floor((tile.north - north) / tile.res_y) - 1)
    r1 = min(tile.height, math.ceil((tile.north - south) / tile.res_y) + 1)
    return (r0, r1, c0, c1) if (r1 > r0 and c1 > c0) else None


#: Points and normals of a whole tile (48 bytes per padded pixel) are computed once when they fit
#: this budget; bigger tiles compute them per image window (more work, bounded memory).
TILE_GEOMETRY_BYTES = 128 * 2**20


class _Geometry:
    """The tile's DEM on the padded grid, and body-fixed points and normals per image window.

    Both ways give the same bytes (normals use the same neighbours, one halo pixel
    around a window); whole-tile geometry is computed once when it fits
    :data:`TILE_GEOMETRY_BYTES`, since images that cover most of a tile would repeat it.
    """

    def __init__(self, scene: Scene, tile):
        s = scene.settings
        self.tile = tile
        self.dem = read_dem_onto_grid(scene.dems, tile.padded_transform, tile.padded_shape, scene.crs, s.no_dem_data_val)
        self.lon, self.lat = geometry.lonlat_grid(tile.padded_transform, tile.padded_shape)
        self.whole = None
        if 48 * self.dem.size <= TILE_GEOMETRY_BYTES:
            pts = self._points(slice(None), slice(None))
            self.whole = (pts, geometry.dem_normals(pts))

    def _points(self, rs, cs):
        return geometry.body_fixed(self.lon[rs, cs], self.lat[rs, cs], np.nan_to_num(self.dem[rs, cs], nan=0.0))

    def window(self, r0, r1, c0, c1):
        """Points (km), normals and no-DEM mask of unpadded window rows r0:r1, cols c0:c1."""
        p = self.tile.pad
        rs, cs = slice(r0 + p, r1 + p), slice(c0 + p, c1 + p)
        bad = ~np.isfinite(self.dem[rs, cs])
        if self.whole is not None:
            return self.whole[0][rs, cs], self.whole[1][rs, cs], bad
        pts = self._points(slice(r0 + p - 1, r1 + p + 1), slice(c0 + p - 1, c1 + p + 1))
        return pts[1:-1, 1:-1], geometry.dem_normals(pts)[1:-1, 1:-1], bad

    def inner_dem(self, tile):
        return self.dem[tile.inner]

    def lonlat(self, r0, r1, c0, c1):
        """Longitude and latitude (degrees) of unpadded window rows r0:r1, cols c0:c1."""
        p = self.tile.pad
        return self.lon[r0 + p:r1 + p, c0 + p:c1 + p], self.lat[r0 + p:r1 + p, c0 + p:c1 + p]


def tile_geometry(scene: Scene, tile):
    """DEM (m), body-fixed points (km), normals and the no-DEM mask of the whole unpadded tile."""
    geo = _Geometry(scene, tile)
    pts, normals, bad = geo.window(0, tile.height, 0, tile.width)
    return geo.inner_dem(tile), pts, normals, bad


def saturation_of(dtype: str) -> float | None:
    """The saturated value of an integer DRG (its type's maximum, e.g. 255); None for float DRGs."""
    dt = np.dtype(dtype)
    return float(np.iinfo(dt).max) if dt.kind in "ui" else None


def gather(scene: Scene, t: int, lut: np.ndarray | None = None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Read and reduce every image over tile ``t``: ``(observations, per-pixel arrays)`` (see module docstring).

    The ``usable`` flag (valid, lit, not saturated, not in a cast shadow, DEM, incidence
    <= 85 degrees and cos e > 0) and the blending weight are folded into ``weight``;
    observations with zero weight are dropped.  ``lut``: camera response g over 0..255
    (seed 002), applied to each DRG's DN before it is resampled onto the tile grid.
    """
    s = scene.settings
    model = solver_model(s)
    tile = scene.tiles[t]
    h, w = tile.height, tile.width
    geo = _Geometry(scene, tile) if model.needs_geometry else None
    thresh = s.shadow_thresh if s.shadow_type == shadows.THRESHOLD else None
    with_cos_i = geo is not None and s.shadow_type == shadows.LAMBERT_RATIO
    windows = {int(k): win for k in scene.tile_images[t] if (win := image_window(tile, scene.images[k].lonlat_bounds))}
    cast = cast_shadow_masks(scene, tile, windows) if geo is not None and s.uses_cast_shadows else {}
    kept = []  # (k, window, window blending weights, then the observations: pix, value, weight, layers)
    weights_sum = np.zeros((h, w))
    for k, win in windows.items():
        r0, r1, c0, c1 = win
        sub = tile.transform @ tile.transform.translation(c0, r0)
        info = scene.images[k]
        got = read_drg_onto_grid(info, scene.profiles[k], sub, (r1 - r0, c1 - c0), scene.crs, thresh,
                                 saturation=saturation_of(info.dtype), lut=lut)
        if got is None:
            continue
        val, ok, wt, use = got
        use &= val > 0
        if k in cast:
            use &= ~cast[k]
        layers = {}
        if geo is not None:
            pts, normals, bad = geo.window(*win)
            ci, ce, al = geometry.illumination(pts, normals, scene.sun[k], scene.spacecraft[k])
            use &= ~bad & (ci >= MIN_COS_INCIDENCE_MODEL) & (ce > 0)
            lon, lat = geo.lonlat(*win)
            layers = model.layers(ci, ce, al, lon=lon, lat=lat)
            if with_cos_i:
                layers["cos_i"] = ci
        wb = (wt if s.use_weights else ok).astype(np.float32)
        sel = np.nonzero(use & (wb > 0))
        if not use.any():
            continue
        weights_sum[r0:r1, c0:c1] += wb  # float64, images in tile order
        pix = ((sel[0] + r0) * w + (sel[1] + c0)).astype(np.int32)
        # compact at once: only the window's blending weights stay (for eq. 7's denominator)
        kept.append((int(k), win, wb, pix, val[sel], wb[sel], {n: np.asarray(layers[n])[sel].astype(np.float32) for n in layers}))
    weights_sum32 = weights_sum.astype(np.float32)
    wblend_sum = np.zeros((h, w))
    names = model.layer_names + (("cos_i",) if with_cos_i else ())
    parts: dict[str, list] = {n: [] for n in ("pix", "image", "weight", *names)}
    for k, (r0, r1, c0, c1), wb, pix, val, weight, layers in kept:
        if s.use_normalized_cost_fun:
            with np.errstate(invalid="ignore", divide="ignore"):
                wb = np.where(wb > 0, wb / weights_sum32[r0:r1, c0:c1], 0.0).astype(np.float32)
                weight = (weight / weights_sum32.ravel()[pix]).astype(np.float32)
        wblend_sum[r0:r1, c0:c1] += wb
        parts["pix"].append(pix)
        parts["image"].append(val)
        parts["weight"].append(weight)
        for n in names:
            parts[n].append(layers[n])
    obs = {n: (np.concatenate(v) if v else np.zeros(0, np.int32 if n == "pix" else np.float32)) for n, v in parts.items()}
    obs["image"] = obs["image"].astype(np.float32)
    obs["index"] = np.array([k for k, *_ in kept], np.int32)
    obs["start"] = np.concatenate([[0], np.cumsum([len(p) for p in parts["pix"]])]).astype(np.int64)
    per_pixel = {"weights_sum": weights_sum32, "wblend_sum": wblend_sum}
    if geo is not None:
        per_pixel["dem"] = geo.inner_dem(tile)
    return obs, per_pixel


def image_of_observation(obs) -> np.ndarray:
    """Local image number (0..K-1) of every observation."""
    return np.repeat(np.arange(len(obs["index"])), np.diff(obs["start"]))
