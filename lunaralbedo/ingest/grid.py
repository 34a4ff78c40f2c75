"""Output grids (geographic, degrees on the 1737.4 km sphere) and bilinear sampling (pure NumPy)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from rasterio.transform import Affine

from ..constants import MOON_RADIUS_M
from ..model.geometry import lonlat_grid


@dataclass(frozen=True)
class Grid:
    """A north-up geographic grid: ``transform`` maps (col, row) to (lon, lat) degrees."""

    transform: Affine
    shape: tuple[int, int]

    @property
    def res(self) -> tuple[float, float]:
        return self.transform.a, -self.transform.e

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """``(west, south, east, north)`` in degrees."""
        h, w = self.shape
        west, north = self.transform.c, self.transform.f
        return west, north - h * self.res[1], west + w * self.res[0], north

    def lonlat(self):
        return lonlat_grid(self.transform, self.shape)

    def crop(self, west: float, south: float, east: float, north: float, margin: int = 1) -> "Grid | None":
        """The sub-grid (same pixel alignment) covering a lon/lat box plus ``margin`` pixels; None if empty."""
        rx, ry = self.res
        c0 = max(0, math.floor((west - self.transform.c) / rx) - margin)
        c1 = min(self.shape[1], math.ceil((east - self.transform.c) / rx) + margin)
        r0 = max(0, math.floor((self.transform.f - north) / ry) - margin)
        r1 = min(self.shape[0], math.ceil((self.transform.f - south) / ry) + margin)
        if c1 <= c0 or r1 <= r0:
            return None
        return Grid(self.transform * Affine.translation(c0, r0), (r1 - r0, c1 - c0))


def aligned_grid(res_deg: tuple[float, float], box: tuple[float, float, float, float],
                 origin: tuple[float, float] = (0.0, 0.0)) -> Grid:
    """A grid of pixel size ``res_deg`` aligned on ``origin`` (lon, lat) covering ``box`` (west, south, east, north)."""
    rx, ry = res_deg
    west, south, east, north = box
    c0 = math.floor((west - origin[0]) / rx + 1e-9)
    c1 = math.ceil((east - origin[0]) / rx - 1e-9)
    r0 = math.floor((origin[1] - north) / ry + 1e-9)
    r1 = math.ceil((origin[1] - south) / ry - 1e-9)
    t = Affine(rx, 0.0, origin[0] + c0 * rx, 0.0, -ry, origin[1] - r0 * ry)
    return Grid(t, (max(1, r1 - r0), max(1, c1 - c0)))


def mpp_to_degrees(mpp: float) -> float:
    """Pixel size in degrees of arc (on the 1737.4 km sphere) for ``mpp`` metres per pixel."""
    return math.degrees(mpp / MOON_RADIUS_M)


def bilinear(image: np.ndarray, col, row) -> np.ndarray:
    """Bilinear samples of ``image`` at 0-based pixel-centre coordinates; NaN outside or next to NaN.

    Coordinates within half a pixel of the border are clamped to the edge pixels.
    """
    h, w = image.shape
    col = np.asarray(col, dtype=np.float64)
    row = np.asarray(row, dtype=np.float64)
    ok = np.isfinite(col) & np.isfinite(row) & (col >= -0.5) & (col <= w - 0.5) & (row >= -0.5) & (row <= h - 0.5)
    c = np.clip(np.where(ok, col, 0.0), 0.0, w - 1.0)
    r = np.clip(np.where(ok, row, 0.0), 0.0, h - 1.0)
    c0 = np.minimum(np.floor(c).astype(np.int64), max(w - 2, 0))
    r0 = np.minimum(np.floor(r).astype(np.int64), max(h - 2, 0))
    c1 = np.minimum(c0 + 1, w - 1)
    r1 = np.minimum(r0 + 1, h - 1)
    fc, fr = c - c0, r - r0
    v = (image[r0, c0] * (1 - fc) * (1 - fr) + image[r0, c1] * fc * (1 - fr)
         + image[r1, c0] * (1 - fc) * fr + image[r1, c1] * fc * fr)
    return np.where(ok, v, np.nan)
