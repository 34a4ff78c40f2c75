"""GeoTIFF outputs, written atomically (temp file + rename): at once, or a block of rows at a time.

:func:`write_geotiff` writes whole arrays.  :class:`GeoTiffRows` writes one raster a block of
rows at a time, so that a caller holds only the rows it is writing, not the whole raster: the
solver's tile outputs (albedo, error, DEM, weight sums) of a tile bigger than one block of its
memory budget (:mod:`lunaralbedo.engine.observations`).  Both give the same file: the same
profile, the same pixels, and, when each block of rows but the last is a whole number of the
file's 256-row blocks (:data:`BLOCK`), the same compressed blocks in the same order.  Rows that
end inside a block of the file are correct as well: GDAL keeps the block in its cache until the
next rows fill it (or writes it and reads it back, a copy of that block left unused in the file).
Both leave to GDAL the blocks that hold nothing but its fill value (:func:`write_rows`): narrow strips
over big tiles leave most blocks of the solver's outputs empty.
"""
from __future__ import annotations

import contextlib
import math
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
                    threads: int = 1, sparse: bool = False) -> dict:
    """The rasterio profile of a GeoTIFF written here (see :func:`write_geotiff` for the choices).  ``sparse``: the
    blocks never written are left out of the file (GDAL's SPARSE_OK; readers give them the no-data value, else 0),
    where GDAL would otherwise store a compressed block of fill values in each of their places: a tile far bigger
    than its images (121 294 x 121 294 px under a 300 x 250 px NAC crop: 264 MB per output, 37 KB sparse)."""
    profile = dict(driver="GTiff", width=width, height=height, count=count, dtype=dtype, transform=transform,
                   crs=crs, nodata=nodata, compress=compress)
    if compress == "zstd":
        profile.update(zstd_level=1, predictor=predictor or (3 if np.dtype(dtype).kind == "f" else 2))
    if height >= 16 and width >= 16:
        profile.update(tiled=height > BLOCK or width > BLOCK)
    if threads > 1 and compress:
        profile.update(num_threads=int(threads))
    if sparse:
        profile.update(sparse_ok=True)
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
            write_rows(dst, arr.astype(dtype, copy=False), 0)
            for k, text in enumerate(descriptions or ()):
                dst.set_band_description(k + 1, text)
            for k, band_tags in enumerate(tags or ()):
                dst.update_tags(k + 1, **band_tags)


def fill_bits(dtype, nodata: float | None) -> int | None:
    """The bit pattern of the pixels GDAL gives a block never written (its no-data value, else 0) in ``dtype``;
    None when the no-data value is not exactly one of ``dtype``'s (GDAL would clamp or round it: no block is left
    to it then)."""
    with np.errstate(all="ignore"):
        value = np.array(0 if nodata is None else nodata).astype(dtype)
    exact = nodata is None or float(value) == float(nodata) or (math.isnan(nodata) and np.isnan(value))
    return int(value.view(f"u{value.itemsize}")) if exact else None


def empty_blocks(bands: np.ndarray, fill: int) -> np.ndarray:
    """Per :data:`BLOCK`-wide column block of ``bands`` (``(count, rows, width)``): True where every pixel of every band
    has the bits ``fill`` (a block GDAL writes by itself when it is never written)."""
    u = bands.view(f"u{bands.dtype.itemsize}")
    starts = np.arange(0, bands.shape[2], BLOCK)
    empty = (u[:, 0, starts] == fill).all(axis=0)  # the first pixel of each block decides most
    for b in np.flatnonzero(empty):
        empty[b] = bool((u[:, :, starts[b]:starts[b] + BLOCK] == fill).all())
    return empty


def write_rows(dst, bands: np.ndarray, row0: int, col0: int = 0) -> None:
    """Write ``bands`` (``(count, rows, width)``, the raster's dtype) as rows ``row0:``, columns ``col0:`` of the open
    GeoTIFF ``dst``.

    A :data:`BLOCK` x :data:`BLOCK` block of the file that these rows cover whole and that holds only the value GDAL
    gives blocks never written (:func:`fill_bits`: the no-data value, else 0; the same bits) is not written: GDAL
    compresses one such block when it closes the file and writes it in each of their places, where compressing each
    took 1.9-4.8 ns per pixel (narrow strips over big tiles leave most blocks of their outputs empty).  The same file
    contents (the same pixels, every block present) for any split of the rows into whole blocks of the file.
    ``col0`` a multiple of :data:`BLOCK` keeps the blocks of the columns written whole as well.
    """
    _, n, w = bands.shape
    fill = fill_bits(bands.dtype, dst.nodata)
    skip = []  # (first row, rows, empty column blocks) of the rows' whole blocks of the file
    h = dst.height
    for a in range(0, n if fill is not None and col0 % BLOCK == 0 else 0, BLOCK):
        r = row0 + a
        rows = min(BLOCK, n - a)
        if r % BLOCK == 0 and (rows == BLOCK or r + rows == h):
            empty = empty_blocks(bands[:, a:a + rows], fill)
            if w % BLOCK and col0 + w < dst.width:  # a last column block cut short is not whole: written
                empty[-1] = False
            if empty.any():
                skip.append((a, rows, empty))
    if not skip:
        dst.write(bands, window=Window(col0, row0, w, n))
        return
    done = 0
    for a, rows, empty in skip:
        if a > done:  # rows before these, written whole
            dst.write(bands[:, done:a], window=Window(col0, row0 + done, w, a - done))
        for c0, c1 in _runs(~empty):
            x0, x1 = c0 * BLOCK, min(c1 * BLOCK, w)
            dst.write(bands[:, a:a + rows, x0:x1], window=Window(col0 + x0, row0 + a, x1 - x0, rows))
        done = a + rows
    if done < n:
        dst.write(bands[:, done:], window=Window(col0, row0 + done, w, n - done))


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` of each run of True in ``flags``."""
    edges = np.flatnonzero(np.diff(np.concatenate([[False], flags, [False]]).astype(np.int8)))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


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

    def write(self, rows: np.ndarray, row0: int, col0: int = 0) -> None:
        """Write ``rows`` (2-D) as rows ``row0:row0 + len(rows)``, columns ``col0:col0 + rows.shape[1]`` (the other
        columns of those rows keep the fill value: :func:`write_rows`)."""
        rows = np.asarray(rows)
        if (rows.ndim != 2 or not 0 <= col0 <= self.shape[1] - rows.shape[1]
                or not 0 <= row0 <= self.shape[0] - rows.shape[0]):
            raise ValueError(f"{self.path}: rows of shape {rows.shape} at row {row0}, column {col0} do not fit a "
                             f"raster of {self.shape}")
        with raster_errors(self.path, "write"):
            if self._dst is None:
                self._open()
            # as one band of a 3-D array: rasterio's 2-D write with a band index took ~1.5 ms more per 1000 x 1000 px
            write_rows(self._dst, rows.astype(self.dtype, copy=False)[None], row0, col0)
        self._rows += rows.shape[0]

    def skip(self, rows: int) -> None:
        """Count ``rows`` rows as written, left to the fill value (the no-data value, else 0): rows no image reaches."""
        self._rows += int(rows)

    def close(self) -> None:
        """Finish the file and rename it onto ``path`` (every row must have been written)."""
        if self._rows != self.shape[0]:
            self.abort()
            raise OutputError(f"{self.path}: {self._rows} of {self.shape[0]} rows were written")
        with raster_errors(self.path, "write"):
            if self._dst is None:  # every row skipped: the file of fill values
                self._open()
            stack, self._stack, self._dst = self._stack, None, None
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
