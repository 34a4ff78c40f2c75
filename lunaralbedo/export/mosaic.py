"""GIS products: the whole result as one Cloud-Optimized GeoTIFF, and the 1/4-resolution tiles.

* ``albedo_mosaic.tif`` / ``error_mosaic.tif``: one band float32, NaN = no data,
  on the native grid of the tiles (:func:`~.sources.native_grid`), continuous
  longitudes, nearest-neighbour copy of the tiles (solver tiles land exactly on
  it), internal 256-px tiles, deflate, average overviews down to one block
  (none when the image fits in one 256-px block), written with rio-cogeo.  The
  mosaic is read in 2048-px blocks (one task each, written to scratch files);
  one last task copies them into one raster and writes the COG.
* ``albedo_sub4/tile_*.tif``: each tile on the same bounds with ``w // 4`` by
  ``h // 4`` pixels (the legacy sizes, e.g. 95 -> 23), by default GDAL average
  resampling ignoring no-data pixels (when the size divides by 4 this is exactly
  the mean of the valid pixels of each 4x4 block); ``nearest`` gives the legacy
  values (PhotometryTK took the pixel nearest to each coarse pixel centre).
  Float32 tiles stay float32 (NaN = no data); legacy uint8 tiles stay uint8
  gray + alpha (255 where any pixel of the block had data).
"""
from __future__ import annotations

import math
import tempfile
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.enums import Resampling
from rasterio.windows import Window
from rio_cogeo.cogeo import cog_translate
from rio_cogeo.profiles import cog_profiles

from ..io.atomic import TMP_PREFIX, atomic_path
from ..io.guard import raster_errors
from ..io.geotiff import write_geotiff
from ..model.grid import Grid
from .sources import Source, read_region

COG_BLOCK = 256
MOSAIC_BLOCK = 2048  # pixels a side of one mosaic task


def overview_count(height: int, width: int, block: int = COG_BLOCK) -> int:
    """Overview levels until the whole image fits in one block (GDAL's COG driver rule)."""
    return max(0, math.ceil(math.log2(max(height, width) / block)))


def block_grids(grid: Grid, size: int = MOSAIC_BLOCK) -> list[tuple[int, int, Grid]]:
    """``(row_off, col_off, sub-grid)`` of the ``size``-pixel blocks of ``grid`` (one mosaic task each)."""
    out = []
    for r0 in range(0, grid.height, size):
        r1 = min(grid.height, r0 + size)
        for c0 in range(0, grid.width, size):
            c1 = min(grid.width, c0 + size)
            out.append((r0, c0, grid.window(c0, r0, c1 - c0, r1 - r0)))
    return out


def write_mosaic_block(sources: Sequence[Source], row_off: int, col_off: int, block: Grid, path: str | Path) -> dict:
    """Task: one block of a mosaic (nearest-neighbour copy of the tiles) as a scratch GeoTIFF."""
    vals = read_region(sources, block, Resampling.nearest)
    profile = dict(driver="GTiff", width=block.width, height=block.height, count=1, dtype="float32",
                   transform=block.transform, nodata=np.nan)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(vals, 1)
    return {"path": str(path), "row_off": row_off, "col_off": col_off, "valid": int(np.isfinite(vals).sum())}


def assemble_cog(blocks: Sequence[dict], grid: Grid, crs_wkt: str, path: str | Path) -> dict:
    """Task: copy the blocks into one scratch raster and write it as a COG at ``path`` (atomically)."""
    path = Path(path)
    profile = dict(
        driver="GTiff", width=grid.width, height=grid.height, count=1, dtype="float32",
        transform=grid.transform, crs=CRS.from_wkt(crs_wkt) if crs_wkt else None, nodata=np.nan,
        tiled=True, blockxsize=COG_BLOCK, blockysize=COG_BLOCK,  # uncompressed scratch copy: speed over size
    )
    with tempfile.TemporaryDirectory(prefix=TMP_PREFIX, dir=path.parent) as tmpdir:
        raw = Path(tmpdir) / "raw.tif"
        with rasterio.open(raw, "w", **profile) as dst:
            for b in blocks:
                with rasterio.open(b["path"]) as src:
                    dst.write(src.read(1), 1, window=Window(b["col_off"], b["row_off"], src.width, src.height))
                Path(b["path"]).unlink()
        cog = cog_profiles.get("deflate")
        cog.update(blockxsize=COG_BLOCK, blockysize=COG_BLOCK, predictor=3)
        with atomic_path(path) as tmp:
            cog_translate(str(raw), str(tmp), cog, overview_level=overview_count(grid.height, grid.width),
                          overview_resampling="average", quiet=True, in_memory=False,
                          config={"GDAL_TIFF_OVR_BLOCKSIZE": str(COG_BLOCK), "GDAL_NUM_THREADS": "ALL_CPUS"})
    with rasterio.open(path) as ds:
        overviews = ds.overviews(1)
    valid = sum(b["valid"] for b in blocks)
    return {"path": str(path), "width": grid.width, "height": grid.height, "valid_pixels": valid, "overviews": overviews}


def sub4_shape(height: int, width: int) -> tuple[int, int]:
    """Size of a 1/4-resolution tile (legacy: ``floor(n / 4)``, at least 1)."""
    return max(1, height // 4), max(1, width // 4)


def write_sub4(src: Source, path: str | Path, resampling: Resampling = Resampling.average, part: Grid | None = None) -> dict:
    """One tile at 1/4 resolution on the same bounds (see the module notes).

    ``Resampling.nearest`` reproduces PhotometryTK's ``albedo_sub4`` exactly (it
    took the pixel nearest to each coarse pixel centre).  ``part`` (a sub-grid of the
    tile's own pixels, file longitudes) crops the tile to the data extent first.
    """
    h4, w4 = sub4_shape(*(part.shape if part is not None else (src.height, src.width)))
    wb, sb, eb, nb = part.bounds if part is not None else src.file_bounds
    dst_transform = Grid.from_bounds((wb, sb, eb, nb), h4, w4).transform
    # only the window of the tile under ``part`` is read (read_region: the sources' continuous longitudes)
    shifted = Grid.from_bounds((wb + src.shift, sb, eb + src.shift, nb), h4, w4)
    out = read_region([src], shifted, resampling, exact_copy=False)
    with raster_errors(src.path), rasterio.open(src.path) as ds:
        crs = ds.crs
    if src.legacy:
        ok = np.isfinite(out)
        gray = np.where(ok, np.rint(np.where(ok, out, 0)), 0).astype(np.uint8)
        profile = dict(driver="GTiff", width=w4, height=h4, count=2, dtype="uint8", transform=dst_transform,
                       crs=crs, compress="deflate", photometric="MINISBLACK", alpha="YES")
        with atomic_path(path) as tmp, rasterio.open(tmp, "w", **profile) as dst:
            dst.write(np.stack([gray, np.where(ok, 255, 0).astype(np.uint8)]))
    else:
        write_geotiff(path, out, dst_transform, crs, nodata=np.nan, dtype="float32")
    return {"path": str(path), "width": w4, "height": h4}
