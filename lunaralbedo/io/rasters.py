"""Raster adapters (rasterio/GDAL): DRG catalogue, windowed reads onto a grid (GeoTIFF writes: :mod:`.geotiff`).

Grids are geographic (degrees of planetocentric longitude/latitude on the Moon's
1737.4 km sphere) unless a DRG says otherwise; every read goes through a window so
memory depends on the output grid, not on the size of the input image.  Target
grids may use continuous longitudes past ±180° (a tile at 180..190); a file whose
longitudes say -180..-170 is read through the grid moved by 360°.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.transform import Affine
from rasterio.warp import reproject, transform_bounds
from rasterio.windows import Window, from_bounds

from ..constants import KEY_LENGTH
from ..errors import DuplicateKeyError, InputError
from ..model.longitude import overlap_shifts
from .guard import open_quietly, raster_errors
from .opened import open_raster

#: GDAL's block cache is per process and by default grows to 5 % of RAM; a solve reads
#: every image once per tile, so a small cache keeps memory bounded by the tile.
GDAL_CACHE_BYTES = 64 * 2**20
rasterio.env.set_gdal_config("GDAL_CACHEMAX", GDAL_CACHE_BYTES)

#: Geographic CRS of the IAU 2015 Moon sphere (radius 1737.4 km), planetocentric, east-positive.
MOON_CRS = CRS.from_string("IAU_2015:30100")

RASTER_SUFFIXES = (".tif", ".tiff", ".cub", ".vrt", ".img")


@dataclass(frozen=True)
class RasterInfo:
    """Header facts of one input raster (no pixels).

    ``bounds`` is ``(west, south, east, north)`` in the raster's CRS units
    (degrees for the geographic Moon CRS).
    """

    key: str
    path: Path
    width: int
    height: int
    transform: Affine
    crs: CRS | None
    bounds: tuple[float, float, float, float]
    count: int
    dtype: str
    nodata: float | None
    geo_bounds: tuple[float, float, float, float] | None = None  # degrees, in geographic_crs(crs)

    @property
    def lonlat_bounds(self) -> tuple[float, float, float, float]:
        """``(west, south, east, north)`` in degrees (the bounds themselves for a geographic CRS)."""
        return self.geo_bounds or self.bounds

    @property
    def lonlat_res(self) -> tuple[float, float]:
        """Pixel size in degrees (for a projected CRS: the extent in degrees over the pixel count)."""
        if self.geo_bounds is None:
            return self.res
        w, s, e, n = self.geo_bounds
        return (e - w) / self.width, (n - s) / self.height

    @property
    def has_alpha(self) -> bool:
        """A second band is read as the alpha / valid mask (legacy DRGs carry one)."""
        return self.count >= 2

    @property
    def res(self) -> tuple[float, float]:
        return abs(self.transform.a), abs(self.transform.e)


def geographic_crs(crs: CRS | None) -> CRS | None:
    """The geographic (lon/lat degrees) CRS of ``crs``'s body: itself if already geographic.

    GDAL's ISIS3 driver presents map-projected cubes in metres (e.g. SimpleCylindrical);
    tiles are always laid out in degrees of their geodetic CRS.
    """
    if crs is None or crs.is_geographic:
        return crs
    import pyproj

    return CRS.from_wkt(pyproj.CRS.from_wkt(crs.to_wkt()).geodetic_crs.to_wkt())


def bounds_in(src_crs: CRS | None, dst_crs: CRS | None, bounds) -> tuple[float, float, float, float]:
    """``bounds`` (west, south, east, north) of ``src_crs`` expressed in ``dst_crs`` (densified edges)."""
    if src_crs is None or dst_crs is None or src_crs == dst_crs:
        return tuple(bounds)
    return tuple(transform_bounds(src_crs, dst_crs, *bounds, densify_pts=21))


def raster_info(path: str | Path, key: str | None = None) -> RasterInfo:
    """Read the header of ``path``; :class:`InputError` naming the file when GDAL cannot open it."""
    path = Path(path)
    with open_quietly(path) as ds:
        if ds.transform == Affine.identity():
            raise InputError(f"{path}: raster has no georeferencing (identity transform)")
        geo = None
        if ds.crs is not None and not ds.crs.is_geographic:
            geo = bounds_in(ds.crs, geographic_crs(ds.crs), ds.bounds)
        return RasterInfo(key=key if key is not None else path.name[:KEY_LENGTH], path=path, width=ds.width,
                          height=ds.height, transform=ds.transform, crs=ds.crs, bounds=tuple(ds.bounds),
                          count=ds.count, dtype=ds.dtypes[0], nodata=ds.nodata, geo_bounds=geo)


def list_rasters(folder: str | Path, what: str = "raster") -> list[Path]:
    """The raster files in ``folder``, sorted by name (auxiliary ``.aux.xml`` files skipped)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: {what} folder not found")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in RASTER_SUFFIXES)
    if not files:
        raise InputError(f"{folder}: no {what} files ({', '.join(RASTER_SUFFIXES)}) in folder")
    return files


def lookup_keys(paths: Sequence[Path]) -> list[str]:
    """The lookup key of each DRG (first 11 characters of its name; the PhotometryTK manual, section 6).

    Two files with the same key raise :class:`DuplicateKeyError` naming both.
    """
    seen: dict[str, Path] = {}
    for p in paths:
        key = p.name[:KEY_LENGTH]
        if key in seen:
            raise DuplicateKeyError(
                f"{seen[key]} and {p} share the lookup key {key!r} (the first {KEY_LENGTH} characters of the name)"
            )
        seen[key] = p
    return list(seen)


def catalog_drgs(folder: str | Path) -> list[RasterInfo]:
    """Headers of every DRG in ``folder``, keyed by :func:`lookup_keys`."""
    paths = list_rasters(folder, "DRG")
    return [raster_info(p, key) for p, key in zip(paths, lookup_keys(paths))]


def intersects(bounds: Sequence[float], box: Sequence[float]) -> bool:
    """Do two ``(west, south, east, north)`` rectangles overlap with positive area?"""
    return bounds[0] < box[2] and box[0] < bounds[2] and bounds[1] < box[3] and box[1] < bounds[3]


def intersects_lon(bounds: Sequence[float], box: Sequence[float]) -> bool:
    """:func:`intersects` modulo 360° in longitude (a DRG at -180..-170 meets a tile at 180..190)."""
    return bool(overlap_shifts(bounds, box))


def _grid_bounds(dst_transform: Affine, dst_shape: tuple[int, int]) -> tuple[float, float, float, float]:
    h, w = dst_shape
    west, north = dst_transform @ (0, 0)
    east, south = dst_transform @ (w, h)
    return (min(west, east), min(south, north), max(west, east), max(south, north))


def _grid_shifts(info: RasterInfo, dst_transform: Affine, dst_shape: tuple[int, int], dst_crs: CRS | None) -> list[Affine]:
    """The target grid moved by the multiples of 360° that bring it onto ``info``'s longitudes.

    Tiles use continuous longitudes (e.g. 180..190) while a DRG's file may say -180..-170:
    the same ground.  Reading through the moved grid gives the same pixels.  ``[dst_transform]``
    when nothing wraps or the target CRS is not geographic.
    """
    if dst_crs is not None and not dst_crs.is_geographic:
        return [dst_transform]
    shifts = overlap_shifts(info.lonlat_bounds, _grid_bounds(dst_transform, dst_shape)) or [0.0]
    return [Affine.translation(-s, 0.0) @ dst_transform for s in shifts]


#: A DRG whose grid matches the target's pixel size and lies an integer number of pixels from it
#: within this fraction of a pixel is copied pixel for pixel instead of warped (bilinear weights
#: would be (1, 0) up to this fraction).  Ingest writes DRGs on the DEM's grid, so this is the usual case.
ALIGNED_TOLERANCE_PX = 1e-6


def aligned_offset(src_transform: Affine, dst_transform: Affine, shape: tuple[int, int],
                   tol: float | None = None) -> tuple[int, int] | None:
    """``(row, col)`` of the target grid's first pixel on the source grid when both grids are aligned, else None.

    Aligned: no rotation, the same pixel size (within ``tol`` pixel over ``shape``) and an
    integer offset (within ``tol`` pixel, default :data:`ALIGNED_TOLERANCE_PX`; negative: never aligned).
    """
    tol = ALIGNED_TOLERANCE_PX if tol is None else tol
    s, d = src_transform, dst_transform
    if tol < 0:
        return None
    if s.b or s.d or d.b or d.d or not s.a or not s.e:
        return None
    h, w = shape
    if abs(d.a - s.a) * max(w, 1) > tol * abs(s.a) or abs(d.e - s.e) * max(h, 1) > tol * abs(s.e):
        return None
    col, row = (d.c - s.c) / s.a, (d.f - s.f) / s.e
    ci, ri = round(col), round(row)
    if abs(col - ci) > tol or abs(row - ri) > tol:
        return None
    return int(ri), int(ci)


def read_onto_grid(
    info: RasterInfo,
    band: int,
    dst_transform: Affine,
    dst_shape: tuple[int, int],
    dst_crs: CRS | None,
    resampling: Resampling = Resampling.bilinear,
    nodata: float | None = None,
) -> np.ndarray:
    """Resample one band of ``info`` onto a target grid; float32 with NaN where no data.

    Only the window of the source that covers the target (plus a 2-pixel margin for
    interpolation) is read; a source on the target's grid (:func:`aligned_offset`) is
    copied pixel for pixel instead of warped.  ``nodata`` overrides the file's own value when the file
    has none.
    """
    out = None
    for t in _grid_shifts(info, dst_transform, dst_shape, dst_crs):
        got = _read_onto_grid_once(info, band, t, dst_shape, dst_crs, resampling, nodata)
        if out is None:  # the first (usually only) shift fills an empty grid: its values as they are
            out = got
            continue
        fill = np.isnan(out)
        out[fill] = got[fill]
    return out


def _read_onto_grid_once(info, band, dst_transform, dst_shape, dst_crs, resampling, nodata) -> np.ndarray:
    src_nodata = info.nodata if info.nodata is not None else nodata
    with raster_errors(info.path), open_raster(info.path) as ds:
        same_crs = dst_crs is None or ds.crs is None or ds.crs == dst_crs
        off = aligned_offset(ds.transform, dst_transform, dst_shape) if same_crs else None
        if off is not None:  # the target's pixels are source pixels: copy them
            r, c = off
            r0, r1, c0, c1 = max(r, 0), min(r + dst_shape[0], ds.height), max(c, 0), min(c + dst_shape[1], ds.width)
            if r1 <= r0 or c1 <= c0:
                return np.full(dst_shape, np.nan, dtype=np.float32)
            src = _read_values(ds, band, Window(c0, r0, c1 - c0, r1 - r0), src_nodata)
            if (r1 - r0, c1 - c0) == tuple(dst_shape):  # the target lies inside the source: its pixels as read
                return src
            out = np.full(dst_shape, np.nan, dtype=np.float32)
            out[r0 - r:r1 - r, c0 - c:c1 - c] = src
            return out
        out = np.full(dst_shape, np.nan, dtype=np.float32)
        win = _source_window(ds, dst_transform, dst_shape, dst_crs)
        win = Window(win.col_off - 2, win.row_off - 2, win.width + 4, win.height + 4).round_offsets().round_lengths()
        win = win.intersection(Window(0, 0, ds.width, ds.height)) if _overlaps(win, ds) else None
        if win is None or win.width <= 0 or win.height <= 0:
            return out
        src = _read_values(ds, band, win, src_nodata)
        reproject(
            source=src,
            destination=out,
            src_transform=ds.window_transform(win),
            src_crs=ds.crs or dst_crs,
            src_nodata=np.nan,
            dst_transform=dst_transform,
            dst_crs=dst_crs or ds.crs,
            dst_nodata=np.nan,
            resampling=resampling,
        )
    return out


def _read_values(ds, band: int, win: Window, nodata: float | None) -> np.ndarray:
    """Band ``band`` of ``ds`` over ``win``: float32, NaN where it equals ``nodata`` (compared in float32), its
    scale and offset applied (ISIS Base/Multiplier, GeoTIFF scale/offset; in float64, rounded once)."""
    src = ds.read(band, window=win, out_dtype=np.float32, masked=False)
    if nodata is not None:  # in place, no index arrays (a boolean-mask assignment made two more passes)
        np.copyto(src, np.float32(np.nan), where=src == np.float32(nodata))
    scale, offset = ds.scales[band - 1], ds.offsets[band - 1]
    if (scale, offset) != (1.0, 0.0):
        src = (src.astype(np.float64) * scale + offset).astype(np.float32)
    return src


def _source_window(ds, dst_transform: Affine, dst_shape: tuple[int, int], dst_crs: CRS | None) -> Window:
    """Window of ``ds`` covering the target grid (in the source's own CRS)."""
    box = bounds_in(dst_crs, ds.crs, _grid_bounds(dst_transform, dst_shape))
    return from_bounds(*box, ds.transform)


def _overlaps(win: Window, ds) -> bool:
    return win.col_off < ds.width and win.row_off < ds.height and win.col_off + win.width > 0 and win.row_off + win.height > 0


def read_dem_onto_grid(
    infos: Sequence[RasterInfo], dst_transform: Affine, dst_shape: tuple[int, int], dst_crs: CRS | None, nodata: float
) -> np.ndarray:
    """Average of every DEM tile resampled (bilinear) onto the grid; float32 metres, NaN where none.

    Overlapping DEM tiles are averaged (:func:`lunaralbedo.model.geometry.merge_dem_layers`,
    the rule ingest uses too; the PhotometryTK manual, section 6); ``nodata`` applies to
    tiles that do not carry their own no-data value.  Scale/offset (ISIS
    Base/Multiplier) are applied, and a tile holding radius (e.g. LOLA or GLD100 cubes,
    ~1.737e6 m) is converted to height above the 1737.4 km sphere.
    """
    from ..model.geometry import merge_dem_layers, radius_to_height

    grid_box = _grid_bounds(dst_transform, dst_shape)
    layers = (radius_to_height(read_onto_grid(info, 1, dst_transform, dst_shape, dst_crs, Resampling.bilinear,
                                              nodata=nodata))[0]
              for info in infos if intersects_lon(info.lonlat_bounds, grid_box))
    return merge_dem_layers(layers, dst_shape, np.float32, owned=True)


def written_windows(ds, rows: int = 1024) -> list[Window]:
    """Windows of band 1 that may hold pixels, in row-major order (a raster of any size in bounded memory).

    A tiled GeoTIFF written sparsely (GDAL leaves out the blocks never written, and
    reads them as no-data) lists its blocks' byte offsets in the ``TIFF`` metadata
    domain (``BLOCK_OFFSET_<col>_<row>``): only the written blocks are returned, each
    row of blocks merged into one window over the columns it spans.  Any other raster
    is cut into bands of ``rows`` rows.
    """
    bh, bw = ds.block_shapes[0]
    if ds.driver != "GTiff" or bw >= ds.width:
        return [Window(0, r, ds.width, min(rows, ds.height - r)) for r in range(0, ds.height, rows)]
    out = []
    for i in range(-(-ds.height // bh)):
        cols = [j for j in range(-(-ds.width // bw)) if ds.get_tag_item(f"BLOCK_OFFSET_{j}_{i}", "TIFF", bidx=1)]
        if cols:
            c0, c1 = cols[0] * bw, min(ds.width, (cols[-1] + 1) * bw)
            out.append(Window(c0, i * bh, c1 - c0, min(bh, ds.height - i * bh)))
    return out


def count_finite(path: str | Path, rows: int = 1024) -> int:
    """Finite pixels of band 1 of a raster, read a window of :func:`written_windows` at a time."""
    with raster_errors(path), rasterio.open(path) as ds:
        return sum(int(np.count_nonzero(np.isfinite(ds.read(1, window=w)))) for w in written_windows(ds, rows))
