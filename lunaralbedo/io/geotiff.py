"""GeoTIFF outputs, written atomically (temp file + rename): at once, or a block of rows at a time.

:func:`write_geotiff` writes whole arrays.  :class:`GeoTiffRows` writes one raster a block of
rows at a time, so that a caller holds only the rows it is writing, not the whole raster: the
solver's tile outputs (albedo, error, DEM, weight sums) of a tile bigger than one block of its
memory budget (:mod:`lunaralbedo.engine.observations`).  Both give the same file: the same
profile, the same pixels, and, when each block of rows but the last is a whole number of the
file's 256-row blocks (:data:`BLOCK`), the same compressed blocks in the same order.  Rows that
end inside a block of the file are correct as well: GDAL keeps the block in its cache until the
next rows fill it (or writes it and reads it back, a copy of that block left unused in the file).
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path
from typing import Sequence

import numpy as np
import rasterio
from rasterio.crs import CRS
from rasterio.transform import Affine
from rasterio.windows import Window

from ..errors import OutputError
from .atomic import atomic_path
from .guard import raster_errors

#: Block height and width of the tiled GeoTIFFs written here (GDAL's default for ``tiled=True``).
BLOCK = 256


def geotiff_profile(count: int, height: int, width: int, dtype: str, transform: Affine, crs: CRS | None,
                    nodata: float | None = None, compress: str = "zstd", predictor: int | None = None,
                    threads: int = 1) -> dict:
    """The rasterio profile of a GeoTIFF written here (see :func:`write_geotiff` for the choices)."""
    profile = dict(driver="GTiff", width=width, height=height, count=count, dtype=dtype, transform=transform,
                   crs=crs, nodata=nodata, compress=compress)
    if compress == "zstd":
        profile.update(zstd_level=1, predictor=predictor or (3 if np.dtype(dtype).kind == "f" else 2))
    if height >= 16 and width >= 16:
        profile.update(tiled=height > BLOCK or width > BLOCK)
    if threads > 1 and compress:
        profile.update(num_threads=int(threads))
    return profile


def write_geotiff(
    path: str | Path,
    bands: np.ndarray | Sequence[np.ndarray],
    transform: Affine,
    crs: CRS | None,
    nodata: float | None = None,
    dtype: str | None = None,
    compress: str = "zstd",
    descriptions: Sequence[str] | None = None,
    tags: Sequence[dict] | None = None,
    predictor: int | None = None,
    threads: int = 1,
) -> None:
    """Write one or more bands as a GeoTIFF, atomically (temp file + rename).

    ``descriptions`` and ``tags`` (one dict per band) are written with the pixels.

    Default compression is ZSTD (level 1) with the floating-point or horizontal
    predictor: about 4x faster to write than DEFLATE at the same size; GDAL >= 2.3,
    QGIS and rasterio read it.  ``predictor`` (1: none, 2: horizontal, 3: floating point)
    overrides that choice: data without smooth rows (the solver's error tiles) compress as
    well without one, and ~30 % faster (docs/performance-history.md, section 0e).  ``threads`` > 1:
    GDAL compresses that many blocks at once (creation option NUM_THREADS; the same file
    contents): for a caller with idle CPUs, such as a one-worker solve (2000 x 2000 px
    float32 tile on 2 CPUs: 60 -> 36 ms, docs/performance-history.md section 0f).
    """
    arr = np.asarray(bands)
    if arr.ndim == 2:
        arr = arr[None]
    dtype = dtype or arr.dtype.name
    profile = geotiff_profile(arr.shape[0], arr.shape[1], arr.shape[2], dtype, transform, crs, nodata, compress,
                              predictor, threads)
    with raster_errors(path, "write"), atomic_path(path) as tmp:
        with rasterio.open(tmp, "w", **profile) as dst:
            dst.write(arr.astype(dtype, copy=False))
            for k, text in enumerate(descriptions or ()):
                dst.set_band_description(k + 1, text)
            for k, band_tags in enumerate(tags or ()):
                dst.update_tags(k + 1, **band_tags)


class GeoTiffRows:
    """A one-band GeoTIFF of ``shape`` written a block of rows at a time (:meth:`write`), atomically.

    The file is created at the first rows, under a temporary name beside ``path``;
    :meth:`close` renames it into place once every row has been written (an
    :class:`~lunaralbedo.errors.OutputError` naming ``path`` if some were not), :meth:`abort`
    removes it.  The other arguments are :func:`write_geotiff`'s.  Not thread-safe: one
    thread writes a file.
    """

    def __init__(self, path: str | Path, shape: tuple[int, int], transform: Affine, crs: CRS | None,
                 dtype: str = "float32", **options):
        self.path, self.shape = Path(path), (int(shape[0]), int(shape[1]))
        self.dtype = dtype
        self._profile = geotiff_profile(1, *self.shape, dtype, transform, crs, **options)
        self._stack: contextlib.ExitStack | None = None
        self._dst = None
        self._rows = 0  # rows written (they come in any order: counted, each row once)

    def write(self, rows: np.ndarray, row0: int) -> None:
        """Write ``rows`` (2-D, the raster's width) as rows ``row0:row0 + len(rows)``."""
        rows = np.asarray(rows)
        if rows.ndim != 2 or rows.shape[1] != self.shape[1] or not 0 <= row0 <= self.shape[0] - rows.shape[0]:
            raise ValueError(f"{self.path}: rows of shape {rows.shape} at row {row0} do not fit a raster of {self.shape}")
        with raster_errors(self.path, "write"):
            if self._dst is None:
                self._open()
            # as one band of a 3-D array: rasterio's 2-D write with a band index took ~1.5 ms more per 1000 x 1000 px
            self._dst.write(rows.astype(self.dtype, copy=False)[None], window=Window(0, row0, self.shape[1], rows.shape[0]))
        self._rows += rows.shape[0]

    def close(self) -> None:
        """Finish the file and rename it onto ``path`` (every row must have been written)."""
        if self._rows != self.shape[0]:
            self.abort()
            raise OutputError(f"{self.path}: {self._rows} of {self.shape[0]} rows were written")
        stack, self._stack, self._dst = self._stack, None, None
        with raster_errors(self.path, "write"):
            stack.close()  # the dataset first (GDAL flushes its blocks), then the rename

    def abort(self) -> None:
        """Remove the unfinished file (nothing at ``path`` changes); nothing happens when none was opened."""
        stack, self._stack, self._dst = self._stack, None, None
        if stack is not None:
            with contextlib.suppress(BaseException):
                stack.__exit__(RuntimeError, RuntimeError("aborted"), None)  # atomic_path removes the temporary file

    def _open(self) -> None:
        stack = contextlib.ExitStack()
        try:
            tmp = stack.enter_context(atomic_path(self.path))
            self._dst = stack.enter_context(rasterio.open(tmp, "w", **self._profile))
        except BaseException:
            with contextlib.suppress(BaseException):
                stack.__exit__(*sys.exc_info())  # atomic_path removes the temporary file (no rename)
            raise
        self._stack = stack
