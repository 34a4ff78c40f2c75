"""The one grid type of the package: a north-up lon/lat raster grid, and bilinear sampling (pure, no I/O).

A :class:`Grid` is an affine ``transform`` mapping (col, row) of pixel *corners* to
(lon, lat) degrees, with ``transform.a > 0`` (pixel width) and ``transform.e < 0``
(north-up), and a ``shape`` ``(height, width)``.  Ingest's orthoprojection grids, the
solver's tiles (:class:`lunaralbedo.engine.tiles.Tile` holds one), the legacy tiles
(:class:`lunaralbedo.legacy.vwgeo.Geo` is one, with the legacy pixel-centre formulas) and
the export mosaics, blocks and pyramid nodes are all grids.

A grid is defined in one of two ways, and keeps its numerics:

* **by its pixels**, ``Grid(transform, shape)`` (ingest, solver tiles, legacy): origin and
  pixel size are exact; the bounds follow (``west + width * res``);
* **by its edges**, :meth:`Grid.from_bounds` (export): the ``(west, south, east, north)``
  edges are exact (a mosaic covers exactly the union of its tiles); the pixel size
  follows (``(east - west) / width``).  Windows of such a grid keep the parent's edges
  where they reach them.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from affine import Affine
from numba import njit

from ..constants import MOON_RADIUS_M
from .geometry import lonlat_grid

Bounds = tuple[float, float, float, float]  # (west, south, east, north), degrees


@dataclass(frozen=True)
class Grid:
    """A north-up geographic grid: ``transform`` maps (col, row) to (lon, lat) degrees; ``shape`` is (rows, cols).

    ``edges`` holds the exact ``(west, south, east, north)`` of a grid defined by its
    edges (:meth:`from_bounds`, :meth:`padded`); None for a grid defined by its pixels.
    """

    transform: Affine
    shape: tuple[int, int]
    edges: Bounds | None = None

    @classmethod
    def from_bounds(cls, bounds: Bounds, height: int, width: int) -> "Grid":
        """The grid of ``height x width`` pixels spanning ``bounds`` exactly."""
        w, s, e, n = bounds
        return cls(Affine((e - w) / width, 0.0, w, 0.0, -(n - s) / height, n), (height, width), tuple(bounds))

    @classmethod
    def from_origin(cls, west: float, north: float, res: tuple[float, float], shape: tuple[int, int]) -> "Grid":
        """The grid whose upper-left corner is ``(west, north)`` with pixels of ``res`` = (x, y) degrees."""
        return cls(Affine(res[0], 0.0, west, 0.0, -res[1], north), (int(shape[0]), int(shape[1])))

    @property
    def height(self) -> int:
        return self.shape[0]

    @property
    def width(self) -> int:
        return self.shape[1]

    @property
    def res(self) -> tuple[float, float]:
        """Pixel size ``(x, y)`` in degrees (both positive)."""
        return self.transform.a, -self.transform.e

    @property
    def bounds(self) -> Bounds:
        """``(west, south, east, north)`` in degrees."""
        if self.edges is not None:
            return self.edges
        h, w = self.shape
        west, north = self.transform.c, self.transform.f
        return west, north - h * self.res[1], west + w * self.res[0], north

    def lonlat(self) -> tuple[np.ndarray, np.ndarray]:
        """Longitude and latitude (degrees) of the pixel centres, each of ``shape``."""
        return lonlat_grid(self.transform, self.shape)

    def window(self, col: int, row: int, width: int, height: int) -> "Grid":
        """The ``height x width`` sub-grid whose pixel (0, 0) is pixel ``(col, row)`` of this grid.

        It may reach outside (negative offsets pad the grid).  A grid defined by its
        pixels keeps its pixel size; one defined by its edges keeps those edges it
        reaches and takes its pixel size from its own edges (see the module notes).
        """
        t = self.transform
        if self.edges is None:
            return replace(self, transform=Affine(t.a, 0.0, t.c + col * t.a, 0.0, t.e, t.f + row * t.e),
                           shape=(height, width))
        w, s, e, n = self.edges
        dx, dy = self.res
        r1, c1 = row + height, col + width
        bounds = (w + col * dx, s if r1 == self.height else n - r1 * dy,
                  e if c1 == self.width else w + c1 * dx, n - row * dy)
        return type(self).from_bounds(bounds, height, width)

    def padded(self, pad: int) -> "Grid":
        """This grid grown by ``pad`` pixels on every side (same pixel size); its edges are the bounds moved out."""
        t = self.transform
        w, s, e, n = self.bounds
        rx, ry = self.res
        return replace(self, transform=Affine(t.a, 0.0, t.c - pad * t.a, 0.0, t.e, t.f - pad * t.e),
                       shape=(self.height + 2 * pad, self.width + 2 * pad),
                       edges=(w - pad * rx, s - pad * ry, e + pad * rx, n + pad * ry))

    def pixel_box(self, box: Bounds, margin: int = 1) -> tuple[int, int, int, int] | None:
        """``(row0, row1, col0, col1)`` of the pixels covering the lon/lat ``box`` plus ``margin``; None if empty."""
        west, south, east, north = box
        rx, ry = self.res
        t = self.transform
        c0 = max(0, math.floor((west - t.c) / rx) - margin)
        c1 = min(self.width, math.ceil((east - t.c) / rx) + margin)
        r0 = max(0, math.floor((t.f - north) / ry) - margin)
        r1 = min(self.height, math.ceil((t.f - south) / ry) + margin)
        return (r0, r1, c0, c1) if (c1 > c0 and r1 > r0) else None

    def crop(self, west: float, south: float, east: float, north: float, margin: int = 1) -> "Grid | None":
        """The sub-grid (same pixel alignment) covering a lon/lat box plus ``margin`` pixels; None if empty."""
        got = self.pixel_box((west, south, east, north), margin)
        if got is None:
            return None
        r0, r1, c0, c1 = got
        return self.window(c0, r0, c1 - c0, r1 - r0)


def aligned_grid(res_deg: tuple[float, float], box: Bounds, origin: tuple[float, float] = (0.0, 0.0)) -> Grid:
    """A grid of pixel size ``res_deg`` aligned on ``origin`` (lon, lat) covering ``box`` (west, south, east, north)."""
    rx, ry = res_deg
    west, south, east, north = box
    c0 = math.floor((west - origin[0]) / rx + 1e-9)
    c1 = math.ceil((east - origin[0]) / rx - 1e-9)
    r0 = math.floor((origin[1] - north) / ry + 1e-9)
    r1 = math.ceil((origin[1] - south) / ry - 1e-9)
    t = Affine(rx, 0.0, origin[0] + c0 * rx, 0.0, -ry, origin[1] - r0 * ry)
    return Grid(t, (max(1, r1 - r0), max(1, c1 - c0)))


#: Round tile sizes (degrees): these times a power of ten.
ROUND_MANTISSAS = (8, 6, 5, 4, 3, 2.5, 2, 1.5, 1)


def round_down(value: float) -> float:
    """The largest of :data:`ROUND_MANTISSAS` times a power of ten that is <= ``value`` (> 0)."""
    k = math.floor(math.log10(value))
    for m in ROUND_MANTISSAS:
        v = float(f"{m * 10.0 ** k:.12g}")
        if v <= value * (1 + 1e-9):
            return v
    return float(f"{10.0 ** k:.12g}")  # pragma: no cover - 1 * 10^k <= value always


def tile_side_deg(res_deg: float, budget_bytes: float, bytes_per_pixel: float, max_deg: float = 4.0) -> float:
    """A round tile size (degrees) whose square tiles of ``res_deg`` pixels hold at most ``budget_bytes``.

    ``side = sqrt(budget / bytes_per_pixel) * res_deg`` rounded down by :func:`round_down`,
    at most ``max_deg`` (the legacy default), at least one pixel.
    """
    side = math.sqrt(budget_bytes / bytes_per_pixel) * res_deg
    return min(max_deg, max(round_down(side), res_deg))


def tile_pixels(tile_size: float, res_deg: float) -> int:
    """Pixels on a side of a ``tile_size``-degree tile of ``res_deg``-degree pixels (as the solver's tiles)."""
    return max(1, math.ceil(tile_size / res_deg - 1e-6))


def mpp_to_degrees(mpp: float) -> float:
    """Pixel size in degrees of arc (on the 1737.4 km sphere) for ``mpp`` metres per pixel."""
    return math.degrees(mpp / MOON_RADIUS_M)


def degrees_to_mpp(deg: float) -> float:
    """Metres per pixel on the 1737.4 km sphere for a pixel of ``deg`` degrees of arc."""
    return math.radians(deg) * MOON_RADIUS_M


@njit(cache=True)
def bilinear_at(image, col, row):
    """One bilinear sample of ``image`` at 0-based pixel-centre coordinates (float64); NaN outside or next to NaN.

    Coordinates within half a pixel of the border are clamped to the edge pixels.  The one
    implementation: :func:`bilinear` runs it over arrays, ingest's fused orthoprojection
    (:mod:`lunaralbedo.ingest.sampling`) calls it per pixel.
    """
    h, w = image.shape
    if not (col >= -0.5 and col <= w - 0.5 and row >= -0.5 and row <= h - 0.5):  # NaN coordinates too
        return np.nan
    c = min(max(col, 0.0), w - 1.0)
    r = min(max(row, 0.0), h - 1.0)
    c0 = min(int(math.floor(c)), max(w - 2, 0))
    r0 = min(int(math.floor(r)), max(h - 2, 0))
    c1 = min(c0 + 1, w - 1)
    r1 = min(r0 + 1, h - 1)
    fc, fr = c - c0, r - r0
    return (image[r0, c0] * (1 - fc) * (1 - fr) + image[r0, c1] * fc * (1 - fr)
            + image[r1, c0] * (1 - fc) * fr + image[r1, c1] * fc * fr)


@njit(cache=True)
def _bilinear_over(image, col, row, out):
    for i in range(col.shape[0]):
        out[i] = bilinear_at(image, col[i], row[i])


def bilinear(image: np.ndarray, col, row) -> np.ndarray:
    """:func:`bilinear_at` over broadcast arrays of 0-based pixel-centre coordinates (float64)."""
    col, row = np.broadcast_arrays(np.asarray(col, dtype=np.float64), np.asarray(row, dtype=np.float64))
    out = np.empty(col.size)
    _bilinear_over(np.asarray(image), np.ascontiguousarray(col).ravel(), np.ascontiguousarray(row).ravel(), out)
    return out.reshape(col.shape)
