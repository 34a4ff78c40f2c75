"""What one tile of each web layer looks like (pure NumPy) and the tile writers of :mod:`..export.tiling`.

* albedo: the gray PNG of the shared 8-bit stretch (:func:`..export.stretch.to_rgba`), as in the KML;
* error: the error map's own percentile stretch through a colour map (``magma``);
* hillshade: the DEM lit from azimuth 315 deg (north-west), 45 deg above the horizon.

All PNGs are RGBA with alpha 0 where there is no data.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..constants import MOON_RADIUS_M
from ..export.pyramid import Node
from ..export.stretch import Stretch, to_dn, to_rgba
from ..export.tiling import write_png

SUN_AZIMUTH_DEG = 315.0
SUN_ALTITUDE_DEG = 45.0


def tile_relpath(level: int, col: int, row: int) -> str:
    """XYZ path of a tile below its layer folder (row 0 at the north edge)."""
    return f"{level}/{col}/{row}.png"


def pixel_size_m(bounds: Sequence[float], shape: tuple[int, int], radius_m: float = MOON_RADIUS_M) -> tuple[np.ndarray, float]:
    """East-west pixel size per row (metres, on the sphere at each row's centre latitude) and the north-south size.

    ``bounds`` are (west, south, east, north) degrees of a north-up grid of ``shape`` (rows, cols).
    """
    w, s, e, n = bounds
    rows, cols = shape
    dlat = (n - s) / rows
    lat = n - (np.arange(rows) + 0.5) * dlat
    dx = np.radians((e - w) / cols) * radius_m * np.cos(np.radians(lat))
    return dx, math.radians(dlat) * radius_m


def hillshade(height_m: np.ndarray, dx_m: np.ndarray | float, dy_m: float,
              azimuth_deg: float = SUN_AZIMUTH_DEG, altitude_deg: float = SUN_ALTITUDE_DEG) -> np.ndarray:
    """Cosine of the angle between the surface normal and the Sun direction, clipped to [0, 1].

    ``height_m`` is a north-up grid (row 0 north) of heights in metres; ``dx_m`` the
    east-west pixel size (scalar or one per row), ``dy_m`` the north-south one.  The
    normal is ``(-dz/dx, -dz/dy, 1)`` (x east, y north, central differences, one-sided
    at the edges); the Sun direction ``(sin az cos alt, cos az cos alt, sin alt)``
    with azimuth clockwise from north.  NaN where the height (or a neighbour) is NaN.
    """
    z = np.asarray(height_m, dtype=np.float64)
    if z.shape[0] < 2 or z.shape[1] < 2:
        return np.full(z.shape, np.nan, dtype=np.float32)
    dzdrow, dzdcol = np.gradient(z)
    dx = np.broadcast_to(np.asarray(dx_m, dtype=np.float64).reshape(-1, 1) if np.ndim(dx_m) else dx_m, z.shape)
    gx, gy = dzdcol / dx, -dzdrow / dy_m  # rows run south
    az, alt = math.radians(azimuth_deg), math.radians(altitude_deg)
    sun = (math.sin(az) * math.cos(alt), math.cos(az) * math.cos(alt), math.sin(alt))
    shade = (-gx * sun[0] - gy * sun[1] + sun[2]) / np.sqrt(gx * gx + gy * gy + 1.0)
    return np.clip(shade, 0.0, 1.0).astype(np.float32)


def colormap_lut(name: str = "magma") -> np.ndarray:
    """(256, 3) uint8 RGB of a matplotlib colour map."""
    from matplotlib import colormaps

    return np.rint(255 * colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3]).astype(np.uint8)


def colored_rgba(values: np.ndarray, stretch: Stretch, lut: np.ndarray) -> np.ndarray:
    """(4, h, w) uint8: the stretched values through ``lut``, alpha 0 where no data."""
    rgb = lut[to_dn(values, stretch)]
    alpha = np.where(np.isfinite(values), 255, 0).astype(np.uint8)
    return np.concatenate([np.moveaxis(rgb, -1, 0), alpha[None]])


def write_tile(out_dir: Path, node: Node, rgba: np.ndarray, tile_size: int) -> None:
    """Write one map tile as a full ``tile_size`` square PNG.

    Leaflet draws every tile into a ``tile_size`` square, so the short tiles at the east and
    south edges of the pyramid (the KML's are cut to the data) are padded with transparent
    pixels on their right and bottom, which keeps the top-left corner where it is.
    """
    _, h, w = rgba.shape
    if (h, w) != (tile_size, tile_size):
        full = np.zeros((4, tile_size, tile_size), dtype=np.uint8)
        full[:, :h, :w] = rgba
        rgba = full
    write_png(out_dir / tile_relpath(*node.key), rgba, node.grid.transform)


@dataclass(frozen=True)
class GrayTiles:
    """Tile writer: the gray PNG of the stretched values (the KML's look)."""

    stretch: Stretch
    tile_size: int

    def __call__(self, out_dir: Path, node: Node, children: Sequence[Node], values: np.ndarray) -> None:
        write_tile(out_dir, node, to_rgba(values, self.stretch), self.tile_size)


@dataclass(frozen=True)
class ColorTiles:
    """Tile writer: the stretched values through a colour map."""

    stretch: Stretch
    lut: np.ndarray
    tile_size: int

    def __call__(self, out_dir: Path, node: Node, children: Sequence[Node], values: np.ndarray) -> None:
        write_tile(out_dir, node, colored_rgba(values, self.stretch, self.lut), self.tile_size)


@dataclass(frozen=True)
class HillshadeTiles:
    """Tile writer: the hillshade of DEM heights (metres), gray 0..255."""

    tile_size: int

    def __call__(self, out_dir: Path, node: Node, children: Sequence[Node], values: np.ndarray) -> None:
        dx, dy = pixel_size_m(node.bounds, values.shape)
        shade = hillshade(values, dx, dy)
        write_tile(out_dir, node, to_rgba(shade, Stretch(0.0, 1.0, "range")), self.tile_size)
