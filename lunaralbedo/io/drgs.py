"""DRGs resampled onto a tile grid with their validity, blending weight and usable flags.

The solver reads every image over each tile it meets (only the window that covers the
tile).  A DRG on the tile grid (:func:`~lunaralbedo.io.rasters.aligned_offset`: same pixel
size, integer offset; ingest writes DRGs on the DEM's grid) is copied pixel for pixel;
other grids go through GDAL's warper (bilinear).
"""
from __future__ import annotations

import numpy as np
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.warp import reproject
from rasterio.windows import Window, from_bounds
from rasterio.windows import transform as window_transform

from .guard import raster_errors
from .opened import open_raster
from .rasters import RasterInfo, _grid_bounds, _grid_shifts, _overlaps, aligned_offset, bounds_in


def read_drg_onto_grid(
    info: RasterInfo,
    profile,
    dst_transform: Affine,
    dst_shape: tuple[int, int],
    dst_crs: CRS | None,
    lit_threshold: float | None = None,
    saturation: float | None = None,
    lut: np.ndarray | None = None,
    resampling: Resampling = Resampling.bilinear,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Resample one DRG onto a target grid: ``(value, valid, weight, lit)`` or None if it misses the grid.

    ``value`` is band 1 (float32, bilinear); ``valid`` is True where all four
    bilinear neighbours are valid (alpha band > 0 and not nodata); ``weight`` the
    blending weight of :func:`lunaralbedo.model.weights.source_weights` (computed from
    ``profile`` on the source grid, then resampled); ``lit`` is True where all four
    neighbours are usable by :func:`lunaralbedo.model.shadows.window_pixels`: lit with the
    threshold ``lit_threshold`` (shadow type 1; always lit when it is None) and, when
    ``saturation`` is given, below it (saturated pixels are left out).  Only the
    covering window (plus a 2-pixel margin) of the source is read.  A DRG on the target's
    grid (:func:`aligned_offset`: same pixel size, integer offset; ingest writes DRGs on the
    DEM's grid) is copied pixel for pixel instead of warped: the same values, and the
    outermost valid pixels keep their exact zero blending weight (GDAL's bilinear gave them
    ~1e-13 from the rounding of its coordinates).

    ``lut`` (a camera response g over 0..255, NaN where undefined; Kim et al.) maps the DN
    to sensor exposure *before* resampling, so the result interpolates exposures (the
    seed's virtual observations, eq. 15); the lit test still uses the DN.
    """
    got = None
    for t in _grid_shifts(info, dst_transform, dst_shape, dst_crs):
        part = _read_drg_once(info, profile, t, dst_shape, dst_crs, lit_threshold, saturation, lut, resampling)
        if got is None or part is None:
            got = got or part
            continue
        take = part[1] & ~got[1]  # pixels only this side of the antimeridian has
        got = tuple(np.where(take, b, a) for a, b in zip(got, part))
    return got


def pixels_on_grid(info: RasterInfo, dst_transform: Affine, dst_shape: tuple[int, int],
                   dst_crs: CRS | None) -> tuple[int, int, int, int] | None:
    """``(r0, r1, c0, c1)``: the pixels of a target grid that a DRG on that grid covers, or None when it is not on
    it (or meets it on both sides of the antimeridian): then it is warped and may reach a pixel more.

    On the grid (:func:`aligned_offset`, the same test as :func:`read_drg_onto_grid`'s), the DRG is read pixel
    for pixel, so no target pixel outside this box gets a valid value; ``r1 <= r0`` or ``c1 <= c0``: none.
    """
    same_crs = dst_crs is None or info.crs is None or info.crs == dst_crs
    shifts = _grid_shifts(info, dst_transform, dst_shape, dst_crs) if same_crs else []
    off = aligned_offset(info.transform, shifts[0], dst_shape) if len(shifts) == 1 else None
    if off is None:
        return None
    r, c = -off[0], -off[1]  # the DRG's first pixel on the target grid
    return max(r, 0), min(r + info.height, dst_shape[0]), max(c, 0), min(c + info.width, dst_shape[1])


def _drg_bands(ds, info, profile, win, lit_threshold, saturation, lut):
    """The four source bands of a DRG window: value (0 where invalid), valid, blending weight, usable (or None)."""
    from ..model import shadows
    from ..model.weights import source_weights

    bands = ds.read((1, 2) if info.has_alpha else (1,), window=win)  # one decode of pixel-interleaved blocks
    value, valid, usable = shadows.window_pixels(bands[0], bands[1] if info.has_alpha else None, info.nodata, lut,
                                                 lit_threshold, saturation)
    r0, c0 = int(win.row_off), int(win.col_off)
    return value, valid, source_weights(profile, r0, c0, valid), usable


def _read_drg_once(info, profile, dst_transform, dst_shape, dst_crs, lit_threshold, saturation, lut, resampling):
    h, w = dst_shape
    with raster_errors(info.path), open_raster(info.path) as ds:
        src_crs = ds.crs or dst_crs
        src_t = info.transform  # the file's georeference, or as a registration moved it (engine/registration.py)
        same_crs = dst_crs is None or ds.crs is None or ds.crs == dst_crs
        off = aligned_offset(src_t, dst_transform, dst_shape) if same_crs else None
        if off is not None:  # the target's pixels are source pixels: copy them
            r, c = off
            r0, r1, c0, c1 = max(r, 0), min(r + h, ds.height), max(c, 0), min(c + w, ds.width)
            if r1 <= r0 or c1 <= c0:
                return None
            win = Window(c0, r0, c1 - c0, r1 - r0)
            val, valid, wt, usable = _drg_bands(ds, info, profile, win, lit_threshold, saturation, lut)
            if not valid.any():
                return None
            lit = valid & usable if usable is not None else valid.copy()
            if (r1 - r0, c1 - c0) == tuple(dst_shape):  # the window lies inside the DRG: its bands as read
                return val, valid, wt, lit
            out = (np.zeros(dst_shape, np.float32), np.zeros(dst_shape, bool), np.zeros(dst_shape, np.float32),
                   np.zeros(dst_shape, bool))
            inner = (slice(r0 - r, r1 - r), slice(c0 - c, c1 - c))
            out[0][inner], out[1][inner], out[2][inner], out[3][inner] = val, valid, wt, lit  # 0 where not valid
            return out
        win = from_bounds(*bounds_in(dst_crs, ds.crs, _grid_bounds(dst_transform, dst_shape)), src_t)
        win = Window(win.col_off - 2, win.row_off - 2, win.width + 4, win.height + 4).round_offsets().round_lengths()
        if not _overlaps(win, ds):
            return None
        win = win.intersection(Window(0, 0, ds.width, ds.height))
        val, valid, wt, usable = _drg_bands(ds, info, profile, win, lit_threshold, saturation, lut)
        src_transform = window_transform(win, src_t)
    bands = [val, valid.astype(np.float32), wt] + ([usable.astype(np.float32)] if usable is not None else [])
    src = np.stack(bands)
    dst = np.zeros((len(bands), h, w), dtype=np.float32)
    reproject(
        source=src,
        destination=dst,
        src_transform=src_transform,
        src_crs=src_crs,
        dst_transform=dst_transform,
        dst_crs=dst_crs or src_crs,
        resampling=resampling,
    )
    ok = dst[1] > 0.9999
    if not ok.any():
        return None
    lit = ok & (dst[3] > 0.9999) if usable is not None else ok
    return dst[0], ok, np.where(ok, dst[2], 0.0).astype(np.float32), lit
