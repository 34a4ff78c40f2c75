"""The albedo (or error) tiles of a RESULTS_DIR as export sources, and windowed reads onto any grid.

Two tile forms are accepted (see ``lunaralbedo solve``):

* default mode: one band float32, NaN (or the nodata tag) = no data;
* legacy mode: uint8 gray + band 2 alpha (0 = no data, 255 = data), like PhotometryTK.

Longitudes are made continuous before anything else: when the tiles cross the
±180° meridian (e.g. ``tile_176E...`` and ``tile_180W...``) the tiles east of the
cut are shifted by +360°, so the mosaic and the KML cover e.g. 176°..184°
(GDAL's ``FIX_ANTIMERIDIAN`` convention, which Google Earth accepts).  The cut is
placed in the widest longitude gap between tiles.  Latitudes are clipped to
[-90°, 90°] (legacy tiles can overshoot the pole by a fraction of a pixel).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.warp import reproject
from rasterio.windows import Window, from_bounds

from ..errors import InputError
from ..io.guard import open_quietly, raster_errors
from ..io.rasters import intersects  # noqa: F401  (used here and by the other export modules)
from ..model.grid import Bounds, Grid
from ..model.longitude import longitude_shifts  # noqa: F401  (re-exported)

TILE_GLOB = "tile_*.tif"


@dataclass(frozen=True)
class Source:
    """Header facts of one tile; ``bounds`` are in the continuous longitude range (``shift`` applied)."""

    path: Path
    width: int
    height: int
    transform: Affine  # the file's own transform (unshifted)
    crs_wkt: str
    legacy: bool  # uint8 gray + alpha band
    nodata: float | None
    shift: float = 0.0  # degrees added to the file's longitudes

    @property
    def res(self) -> tuple[float, float]:
        return abs(self.transform.a), abs(self.transform.e)

    @property
    def file_bounds(self) -> Bounds:
        t = self.transform
        return (t.c, t.f + t.e * self.height, t.c + t.a * self.width, t.f)

    @property
    def bounds(self) -> Bounds:
        w, s, e, n = self.file_bounds
        return (w + self.shift, max(s, -90.0), e + self.shift, min(n, 90.0))

    @property
    def shifted_transform(self) -> Affine:
        return Affine.translation(self.shift, 0.0) @ self.transform


def _header(path: Path) -> Source:
    with open_quietly(path, "tile") as ds:
        t = ds.transform
        if t == Affine.identity() or t.b != 0 or t.d != 0 or t.a <= 0 or t.e >= 0:
            raise InputError(f"{path}: tile is not a north-up georeferenced raster")
        if ds.crs is not None and not ds.crs.is_geographic:
            raise InputError(f"{path}: tile CRS must be geographic (lon/lat degrees), got {ds.crs}")
        legacy = ds.count >= 2 and ds.dtypes[0] == "uint8"
        return Source(path=path, width=ds.width, height=ds.height, transform=t,
                      crs_wkt=ds.crs.to_wkt() if ds.crs is not None else "", legacy=legacy, nodata=ds.nodata)


def find_sources(folder: str | Path, what: str = "albedo") -> list[Source]:
    """Every ``tile_*.tif`` of ``folder`` (sorted by name), longitudes made continuous.

    :class:`InputError` naming the folder when it is missing or holds no tile.
    """
    folder = Path(folder)
    files = sorted(folder.glob(TILE_GLOB)) if folder.is_dir() else []
    if not files:
        raise InputError(f"{folder}: no {what} tiles (tile_*.tif) found; run `lunaralbedo solve` first")
    heads = [_header(p) for p in files]
    shifts = longitude_shifts([(h.file_bounds[0], h.file_bounds[2]) for h in heads])
    return [Source(**{**h.__dict__, "shift": d}) for h, d in zip(heads, shifts)]


def union_bounds(sources: Sequence[Source]) -> Bounds:
    """Union of the source bounds (continuous longitudes, latitudes clipped to ±90°)."""
    b = np.array([s.bounds for s in sources])
    west, east = float(b[:, 0].min()), float(b[:, 2].max())
    east = min(east, west + 360.0)
    return (west, max(float(b[:, 1].min()), -90.0), east, min(float(b[:, 3].max()), 90.0))


def native_grid(sources: Sequence[Source]) -> Grid:
    """The union of the sources at their (shared) pixel size, rounded to whole pixels.

    Solver tiles (whole pixels per tile) give exactly the native grid; legacy tiles,
    whose edges are not pixel-aligned, give a grid within half a pixel of it.
    """
    rx, ry = sources[0].res
    w, s, e, n = union_bounds(sources)
    return Grid.from_bounds((w, s, e, n), max(1, round((n - s) / ry)), max(1, round((e - w) / rx)))


def read_masked(ds, window: Window | None = None, legacy: bool | None = None) -> np.ndarray:
    """Band 1 of an open tile as float32 with NaN where there is no data (alpha 0, nodata or NaN)."""
    legacy = (ds.count >= 2 and ds.dtypes[0] == "uint8") if legacy is None else legacy
    vals = ds.read(1, window=window, out_dtype=np.float32)
    if legacy:
        vals[ds.read(2, window=window) == 0] = np.nan
    elif ds.nodata is not None and not np.isnan(ds.nodata):
        vals[vals == np.float32(ds.nodata)] = np.nan
    return vals


def pixel_offset(src: Source, transform: Affine) -> tuple[int, int] | None:
    """``(col, row)`` of the source pixel at pixel (0, 0) of a grid with ``transform``,
    when the grid has the source's pixel size and whole-pixel offsets; else None."""
    st = src.shifted_transform
    if not (math.isclose(st.a, transform.a, rel_tol=1e-9) and math.isclose(st.e, transform.e, rel_tol=1e-9)):
        return None
    ox, oy = (transform.c - st.c) / st.a, (transform.f - st.f) / st.e
    if abs(ox - round(ox)) > 1e-6 or abs(oy - round(oy)) > 1e-6:
        return None
    return round(ox), round(oy)


def read_region(
    sources: Sequence[Source],
    grid: Grid,
    resampling: Resampling = Resampling.average,
    exact_copy: bool = True,
) -> np.ndarray:
    """The sources resampled onto ``grid``: float32, NaN where no source has data.

    Each overlapping source contributes the window that covers the grid (plus a
    one-pixel margin); where sources overlap, the first one (by name) wins.
    Average resampling ignores no-data pixels, so coarse pixels are the mean of
    the valid fine pixels they cover.  With ``nearest`` and a grid aligned on the
    source's pixels (solver tiles onto their native grid) the pixels are copied
    without GDAL's warper (``exact_copy``; the result is the same, only faster).
    """
    out = np.full(grid.shape, np.nan, dtype=np.float32)
    crs = None
    w, s, e, n = grid.bounds
    gt = grid.transform
    for src in sources:
        if not intersects(src.bounds, grid.bounds):
            continue
        # only the part of the grid this source overlaps is warped
        sw, ss, se, sn = src.bounds
        c0, c1 = max(0, math.floor((max(w, sw) - w) / gt.a)), min(grid.width, math.ceil((min(e, se) - w) / gt.a))
        r0, r1 = max(0, math.floor((n - min(n, sn)) / -gt.e)), min(grid.height, math.ceil((n - max(s, ss)) / -gt.e))
        if c1 <= c0 or r1 <= r0:
            continue
        offset = pixel_offset(src, gt) if exact_copy and resampling == Resampling.nearest else None
        with raster_errors(src.path), rasterio.open(src.path) as ds:
            if offset is not None:
                ox, oy = offset
                c0, c1 = max(c0, -ox), min(c1, ds.width - ox)
                r0, r1 = max(r0, -oy), min(r1, ds.height - oy)
                if c1 <= c0 or r1 <= r0:
                    continue
                part = read_masked(ds, Window(ox + c0, oy + r0, c1 - c0, r1 - r0), src.legacy)
                view = out[r0:r1, c0:c1]
                hole = np.isnan(view)
                view[hole] = part[hole]
                continue
            win = from_bounds(w - src.shift, s, e - src.shift, n, ds.transform)
            win = Window(win.col_off - 1, win.row_off - 1, win.width + 2, win.height + 2)
            win = win.round_offsets(op="floor").round_lengths(op="ceil").intersection(Window(0, 0, ds.width, ds.height))
            vals = read_masked(ds, win, src.legacy)
            crs = ds.crs or crs or CRS.from_epsg(4326)
            part = np.full((r1 - r0, c1 - c0), np.nan, dtype=np.float32)
            reproject(
                source=vals,
                destination=part,
                src_transform=Affine.translation(src.shift, 0.0) @ ds.window_transform(win),
                src_crs=crs,
                src_nodata=np.nan,
                dst_transform=gt @ Affine.translation(c0, r0),
                dst_crs=crs,
                dst_nodata=np.nan,
                resampling=resampling,
            )
        view = out[r0:r1, c0:c1]
        hole = np.isnan(view)
        view[hole] = part[hole]
    return out
