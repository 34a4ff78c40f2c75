"""``noproj`` in blocks of lines: CCD images resampled onto the ideal camera with bounded memory.

A full NAC pair (2 x 5064 x 52224 px -> 10000 x 52224 ideal pixels) does not fit in
memory as whole coordinate maps, so every piece works on a block of ideal lines:

* :class:`NodeMap` - the CCD ``(col, row)`` of the ideal pixels every ``step`` pixels
  (the mapping of :mod:`.ideal`), computed in fixed chunks of node rows and
  interpolated bilinearly to the pixels of a block of lines;
* :class:`SplineRows` - cubic B-spline coefficients of the CCD image (``scipy.ndimage``
  ``spline_filter1d``, mirror boundaries), computed per fixed tile of ``tile`` rows
  from the rows read with a ``margin`` on each side.  The spline prefilter is an
  IIR filter whose influence decays as 0.268^n, so 32 margin rows give the
  coefficients of the whole image to double precision (1e-18);
* :func:`resample_rows` evaluates the spline (``map_coordinates``, ``prefilter=False``)
  from the coefficient rows the block needs.

Chunks and tiles are fixed, independent of the block size, so the output does not
depend on the block size (byte for byte, tested).  Memory: a block of ``B`` lines
uses about ``10 * 8 * B * samples`` bytes, plus a few tiles of ``tile + 2 margin``
CCD rows.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from ..camera.intersect import ray_sphere
from ..constants import MOON_RADIUS_KM

#: Fixed geometry of the tiles and chunks (changing them changes the output in the last bits only).
TILE_ROWS, MARGIN_ROWS, NODE_CHUNK = 512, 32, 32


class NodeMap:
    """0-based CCD ``(col, row)`` of ideal pixels of ``shape``, shifted by ``offset`` (see :mod:`.ideal`)."""

    def __init__(self, ideal, cam, shape, height_m: float, offset=(0.0, 0.0), step: int = 8):
        self.ideal, self.cam, self.shape, self.offset = ideal, cam, shape, offset
        self.radius = MOON_RADIUS_KM + height_m / 1000.0
        lines, samples = shape
        self.rs = np.unique(np.r_[np.arange(0, lines, step), lines - 1])
        self.cs = np.unique(np.r_[np.arange(0, samples, step), samples - 1])
        self._cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def _chunk(self, k: int):
        if k not in self._cache:
            if len(self._cache) > 4:
                self._cache.pop(min(self._cache))
            rows = self.rs[k * NODE_CHUNK:(k + 1) * NODE_CHUNK]
            ll, ss = np.meshgrid(rows, self.cs, indexing="ij")
            o, d = self.ideal.rays(ss + 1.0 - self.offset[0], ll + 1.0 - self.offset[1])
            pts = ray_sphere(o, d, self.radius)
            s, l = self.cam.ground_to_image(np.where(np.isfinite(pts), pts, 0.0))
            self._cache[k] = (s - 1.0, l - 1.0)
        return self._cache[k]

    def nodes(self, i0: int, i1: int):
        """Node values of node rows ``[i0, i1)``."""
        parts = [self._chunk(k) for k in range(i0 // NODE_CHUNK, (i1 - 1) // NODE_CHUNK + 1)]
        s, l = (np.concatenate([p[j] for p in parts]) for j in (0, 1))
        off = i0 - (i0 // NODE_CHUNK) * NODE_CHUNK
        return s[off:off + i1 - i0], l[off:off + i1 - i0]

    def coords(self, l0: int, l1: int, c0: int = 0, c1: int | None = None):
        """CCD ``(col, row)`` of ideal lines ``[l0, l1)`` and columns ``[c0, c1)`` (bilinear between nodes)."""
        from scipy.ndimage import map_coordinates

        c1 = self.shape[1] if c1 is None else c1
        ri = np.interp(np.arange(l0, l1), self.rs, np.arange(self.rs.size))
        ci = np.interp(np.arange(c0, c1), self.cs, np.arange(self.cs.size))
        i0, i1 = int(np.floor(ri[0])), min(self.rs.size, int(np.floor(ri[-1])) + 2)
        grid = np.meshgrid(ri - i0, ci, indexing="ij")
        return tuple(map_coordinates(a, grid, order=1, mode="nearest") for a in self.nodes(i0, i1))

    def valid_columns(self) -> np.ndarray:
        """Ideal columns seen by the CCD on the first, middle and last node rows, bool per column."""
        n = self.rs.size
        seen = np.zeros(self.cs.size, bool)
        for i in sorted({0, n // 2, n - 1}):
            s, l = self.nodes(i, i + 1)
            h, w = self.cam.lines, self.cam.samples
            seen |= ((s >= -0.5) & (s <= w - 0.5) & (l >= -0.5) & (l <= h - 0.5))[0]
        return np.interp(np.arange(self.shape[1]), self.cs, seen.astype(float)) > 0


class SplineRows:
    """B-spline coefficients (float64) of a CCD image read by ``read_rows(start, stop)`` (NaN filled with its mean)."""

    def __init__(self, read_rows: Callable[[int, int], np.ndarray], shape: tuple[int, int]):
        self.read_rows, self.shape = read_rows, shape
        total, count = 0.0, 0
        for r0 in range(0, shape[0], TILE_ROWS):
            rows = read_rows(r0, min(shape[0], r0 + TILE_ROWS))
            ok = np.isfinite(rows)
            total, count = total + float(rows[ok].sum()), count + int(ok.sum())
        self.fill = total / count if count else 0.0
        self._cache: dict[int, np.ndarray] = {}

    def _tile(self, k: int) -> np.ndarray:
        from scipy.ndimage import spline_filter1d

        if k not in self._cache:
            if len(self._cache) > 1:
                self._cache.pop(min(self._cache))
            h = self.shape[0]
            t0, t1 = k * TILE_ROWS, min(h, (k + 1) * TILE_ROWS)
            r0, r1 = max(0, t0 - MARGIN_ROWS), min(h, t1 + MARGIN_ROWS)
            rows = self.read_rows(r0, r1)
            rows = np.where(np.isfinite(rows), rows, self.fill)
            coef = spline_filter1d(spline_filter1d(rows, 3, axis=1, mode="mirror"), 3, axis=0, mode="mirror")
            self._cache[k] = coef[t0 - r0:t1 - r0]
        return self._cache[k]

    def rows(self, r0: int, r1: int) -> np.ndarray:
        """Coefficients of CCD rows ``[r0, r1)``."""
        k0, k1 = r0 // TILE_ROWS, (r1 - 1) // TILE_ROWS
        coef = np.concatenate([self._tile(k) for k in range(k0, k1 + 1)])
        return coef[r0 - k0 * TILE_ROWS:r1 - k0 * TILE_ROWS]


def resample_rows(spline: SplineRows, col: np.ndarray, row: np.ndarray) -> np.ndarray:
    """The CCD image at fractional 0-based ``(col, row)`` by cubic splines; NaN outside the CCD (float32)."""
    from scipy.ndimage import map_coordinates

    h, w = spline.shape
    with np.errstate(invalid="ignore"):
        inside = (col >= -0.5) & (col <= w - 0.5) & (row >= -0.5) & (row <= h - 0.5)
    out = np.full(col.shape, np.nan, dtype=np.float32)
    if not inside.any():
        return out
    r, c = row[inside], col[inside]
    r0, r1 = max(0, int(np.floor(r.min())) - 3), min(h, int(np.floor(r.max())) + 4)
    out[inside] = map_coordinates(spline.rows(r0, r1), [r - r0, c], order=3, mode="mirror", prefilter=False)
    return out
