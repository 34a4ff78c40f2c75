"""Layout of the KML superoverlay: a power-of-two quadtree of PNG tiles (pure functions).

Level 0 is one image of ``(root_height, root_width)`` pixels (each at most
``tile_size``) covering the whole result; level ``k`` has ``2**k`` times as many
pixels in each direction and is cut into ``tile_size`` squares (the last row and
column may be smaller).  The tile ``(k, col, row)`` has as children the tiles
``(k+1, 2col+dc, 2row+dr)`` that exist, so every child covers exactly one quarter
of its parent.  This is the structure GDAL's KMLSUPEROVERLAY reader expects: the
full raster it exposes is ``root size * 2**(levels-1)`` over the root bounds.

Every level covers exactly the union of the albedo tiles (no padding past the
poles or the ±180° cut); the finest level has at least the native resolution
(slightly finer when the native size is not a multiple of ``2**(levels-1)``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

from ..errors import InputError
from ..model.grid import Bounds, Grid
from .sources import intersects

MAX_LEVELS = 20  # GDAL's reader follows at most 20 levels


@dataclass(frozen=True)
class Node:
    """One PNG tile of the pyramid."""

    level: int
    col: int
    row: int
    bounds: Bounds
    width: int
    height: int

    @property
    def grid(self) -> Grid:
        return Grid.from_bounds(self.bounds, self.height, self.width)

    @property
    def key(self) -> tuple[int, int, int]:
        return (self.level, self.col, self.row)


@dataclass(frozen=True)
class Pyramid:
    bounds: Bounds
    levels: int
    tile_size: int
    root_width: int
    root_height: int

    def level_shape(self, level: int) -> tuple[int, int]:
        """(height, width) in pixels of the whole level."""
        return (self.root_height << level, self.root_width << level)

    def level_counts(self, level: int) -> tuple[int, int]:
        """(rows, cols) of tiles in a level."""
        h, w = self.level_shape(level)
        return (math.ceil(h / self.tile_size), math.ceil(w / self.tile_size))

    def node(self, level: int, col: int, row: int) -> Node:
        h, w = self.level_shape(level)
        t = self.tile_size
        c0, c1 = col * t, min((col + 1) * t, w)
        r0, r1 = row * t, min((row + 1) * t, h)
        west, south, east, north = self.bounds
        dx, dy = (east - west) / w, (north - south) / h
        # Shared edges are computed by the same expression, so neighbours abut exactly.
        b = (west + c0 * dx, north - r1 * dy, west + c1 * dx if c1 < w else east, north - r0 * dy)
        if r1 == h:
            b = (b[0], south, b[2], b[3])
        return Node(level, col, row, b, c1 - c0, r1 - r0)

    def children(self, node: Node) -> list[tuple[int, int, int]]:
        if node.level + 1 >= self.levels:
            return []
        rows, cols = self.level_counts(node.level + 1)
        return [
            (node.level + 1, 2 * node.col + dc, 2 * node.row + dr)
            for dr in (0, 1)
            for dc in (0, 1)
            if 2 * node.col + dc < cols and 2 * node.row + dr < rows
        ]

    def covering(self, level: int, footprint: Bounds) -> Iterable[tuple[int, int, int]]:
        """Keys of the level's tiles that overlap ``footprint`` with positive area."""
        h, w = self.level_shape(level)
        west, south, east, north = self.bounds
        t = self.tile_size
        x0 = (footprint[0] - west) / (east - west) * w / t
        x1 = (footprint[2] - west) / (east - west) * w / t
        y0 = (north - footprint[3]) / (north - south) * h / t
        y1 = (north - footprint[1]) / (north - south) * h / t
        rows, cols = self.level_counts(level)
        for row in range(max(0, math.floor(y0) - 1), min(rows, math.ceil(y1) + 1)):
            for col in range(max(0, math.floor(x0) - 1), min(cols, math.ceil(x1) + 1)):
                if intersects(self.node(level, col, row).bounds, footprint):
                    yield (level, col, row)


def levels_needed(native_height: int, native_width: int, tile_size: int) -> int:
    """Fewest levels whose finest level has at least the native resolution."""
    side = max(native_height, native_width)
    return 1 + max(0, math.ceil(math.log2(side / tile_size) - 1e-12))


def plan_pyramid(bounds: Bounds, native_shape: tuple[int, int], tile_size: int = 256, levels: int | None = None) -> Pyramid:
    """The pyramid over ``bounds`` for a native grid of ``(height, width)`` pixels.

    With ``levels`` None, as many levels as the data needs; with fewer, the finest
    level is coarser than the native grid; with more, finer.
    """
    if tile_size < 16:
        raise InputError(f"--tile-size must be at least 16 pixels, got {tile_size}")
    nh, nw = native_shape
    levels = levels_needed(nh, nw, tile_size) if levels is None else int(levels)
    if not 1 <= levels <= MAX_LEVELS:
        raise InputError(f"--levels must be between 1 and {MAX_LEVELS}, got {levels}")
    top = tile_size << (levels - 1)
    scale = min(1.0, top / max(nh, nw))
    fh, fw = max(1, math.floor(nh * scale)), max(1, math.floor(nw * scale))
    f = 1 << (levels - 1)
    return Pyramid(tuple(float(v) for v in bounds), levels, tile_size, math.ceil(fw / f), math.ceil(fh / f))


def present_nodes(pyr: Pyramid, footprints: Sequence[Bounds]) -> dict[int, list[Node]]:
    """Per level, the tiles that overlap at least one albedo tile (the others are not written).

    A parent overlaps a footprint whenever one of its children does, so every
    written tile below the root has a written parent and every branch reaches the
    finest level (GDAL measures the depth along the first branch).
    """
    out: dict[int, list[Node]] = {}
    for level in range(pyr.levels):
        keys = sorted({k for fp in footprints for k in pyr.covering(level, fp)}, key=lambda k: (k[2], k[1]))
        out[level] = [pyr.node(*k) for k in keys]
    return out
