"""The tile grid: TILE_SIZE-degree tiles aligned on multiples of TILE_SIZE.

A tile is named after its unpadded upper-left corner, ``tile_<lon>{E|W}<lat>{N|S}``
(legacy convention: ``tile_4E8S`` covers lon 4..8, lat -12..-8).  Tiles keep the
continuous longitudes of SIMULATION_BOX (170..190 for a box across ±180°): their
georeference may pass 180°, their names do not.  While solving, a
tile is padded by a few pixels so that normals and interpolation at its edge see
their neighbours; outputs are cropped back to the unpadded tile.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

from affine import Affine

from ..errors import SolverError
from ..model.grid import Grid, tile_side_deg
from ..model.longitude import wrap180


def _fmt(value: float, pos: str, neg: str) -> str:
    v = abs(value)
    txt = f"{int(round(v))}" if abs(v - round(v)) < 1e-9 else f"{v:g}".replace(".", "p")
    return f"{txt}{pos if value >= 0 else neg}"


def _fmt_legacy(value: float, pos: str, neg: str) -> str:
    """``%g`` (6 significant digits) of ``|value|``, as C++ ``ostream`` printed the doubles."""
    return f"{(value + 0.0) if value >= 0 else -value:g}{pos if value >= 0 else neg}"


def tile_name(west: float, north: float, legacy: bool = False) -> str:
    """Tile name ``tile_<lon>{E|W}<lat>{N|S}`` from the unpadded upper-left corner (degrees).

    The one tile-naming rule of the package.  Whole degrees print as integers
    (``tile_4E8S``); fractions print with ``p`` for the point (``tile_4p5E8S``),
    or, with ``legacy=True``, as PhotometryTK's ``ostream`` printed them
    (``tile_4.5E8S``: ``%g``, 6 significant digits), the names of the legacy tree.
    The longitude is named in [-180, 180): a tile at 184..188 (continuous longitudes
    east of the antimeridian) is ``tile_176W...``, the one at 180..184 ``tile_180W...``
    (the legacy tree keeps PhotometryTK's names, which never crossed 180 degrees).
    """
    if legacy:
        return f"tile_{_fmt_legacy(west, 'E', 'W')}{_fmt_legacy(north, 'N', 'S')}"
    return f"tile_{_fmt(wrap180(west), 'E', 'W')}{_fmt(north, 'N', 'S')}"


def tile_starts(lo: float, hi: float, tile_size: float, legacy: bool = False) -> list[float]:
    """Starts (west or south edges, degrees) of the TILE_SIZE tiles meeting ``[lo, hi]``, ascending.

    The one rule of the tile grid: tiles start on multiples of ``tile_size``, from
    the one holding ``lo`` to the last starting below ``hi``.  By default ``k * tile_size``
    with a 1e-9 tolerance on the edges (a box ending exactly on a multiple does not
    reach into the next tile).  ``legacy=True`` follows PhotometryTK's loop exactly:
    ``x = ts * floor(lo / ts)`` then ``x += ts`` while ``x < hi`` (no tolerance, the
    starts accumulate the float rounding of ``ts``), as the legacy tile names need.
    """
    if legacy:
        starts, x = [], tile_size * math.floor(lo / tile_size)
        while x < hi:
            starts.append(x)
            x += tile_size
        return starts
    return [k * tile_size for k in tile_indices(lo, hi, tile_size)]


def tile_indices(lo: float, hi: float, tile_size: float) -> range:
    """Indices ``k`` of the tiles ``[k ts, (k+1) ts]`` meeting ``[lo, hi]`` (see :func:`tile_starts`)."""
    return range(math.floor(lo / tile_size + 1e-9), math.ceil(hi / tile_size - 1e-9))


@dataclass(frozen=True)
class Tile:
    """One output tile: its (unpadded) :class:`~lunaralbedo.model.grid.Grid`, index, name and solve padding.

    While solving, the tile is read on ``padded`` (``pad`` more pixels on every side);
    the unpadded tile is ``inner`` of it.
    """

    index: int
    grid: Grid
    size_deg: float
    pad: int

    @property
    def name(self) -> str:
        return tile_name(self.west, self.north)

    # The tile's grid, by the names the tile work uses (degrees, pixels).
    west = property(lambda self: self.grid.transform.c, doc="West edge of the unpadded tile.")
    north = property(lambda self: self.grid.transform.f, doc="North edge of the unpadded tile.")
    res_x = property(lambda self: self.grid.res[0], doc="Pixel width, degrees.")
    res_y = property(lambda self: self.grid.res[1], doc="Pixel height, degrees (positive).")
    width = property(lambda self: self.grid.width, doc="Columns of the unpadded tile.")
    height = property(lambda self: self.grid.height, doc="Rows of the unpadded tile.")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """Unpadded ``(west, south, east, north)`` in degrees."""
        return self.grid.bounds

    @property
    def transform(self) -> Affine:
        return self.grid.transform

    @property
    def padded(self) -> Grid:
        """The solve grid: the tile with ``pad`` pixels more on every side."""
        return self.grid.padded(self.pad)

    @property
    def padded_bounds(self) -> tuple[float, float, float, float]:
        return self.padded.bounds

    @property
    def padded_shape(self) -> tuple[int, int]:
        return self.padded.shape

    @property
    def padded_transform(self) -> Affine:
        return self.padded.transform

    def part(self, box: tuple[int, int, int, int]) -> "Tile":
        """Rows ``r0:r1``, columns ``c0:c1`` of this tile (``box = (r0, r1, c0, c1)``) as a tile of their own (the same
        pixels and padding) (the part of a big tile its images cover, :func:`.observations.footprint`)."""
        r0, r1, c0, c1 = box
        if (r0, r1, c0, c1) == (0, self.height, 0, self.width):
            return self
        return replace(self, grid=self.grid.window(c0, r0, c1 - c0, r1 - r0))

    @property
    def inner(self) -> tuple[slice, slice]:
        """Slices of the padded grid that give the unpadded tile."""
        return (slice(self.pad, self.pad + self.height), slice(self.pad, self.pad + self.width))


def make_tiles(
    box: tuple[float, float, float, float],
    tile_size: float,
    res: tuple[float, float],
    pad: int = 5,
    exact: bool = True,
) -> list[Tile]:
    """Tiles (row-major, north to south, west to east) covering ``box``.

    ``box`` is ``(lon_min, lon_max, lat_min, lat_max)``; ``res`` the (x, y) pixel
    size in degrees.  With ``exact`` the pixel size is adjusted so that an integer
    number of pixels spans the tile exactly (tiles abut without gaps); otherwise
    the given pixel size is kept and the tile has ``ceil(tile_size / res)`` pixels
    (the legacy program's grid).
    """
    lon0, lon1, lat0, lat1 = box
    if res[0] <= 0 or res[1] <= 0:
        raise SolverError(f"pixel size must be positive, got {res}")
    nx = max(1, math.ceil(tile_size / res[0] - 1e-6))
    ny = max(1, math.ceil(tile_size / res[1] - 1e-6))
    rx, ry = (tile_size / nx, tile_size / ny) if exact else res
    tiles = []
    for j in reversed(tile_indices(lat0, lat1, tile_size)):  # north to south
        for i in tile_indices(lon0, lon1, tile_size):
            tiles.append(
                Tile(index=len(tiles), grid=Grid.from_origin(i * tile_size, (j + 1) * tile_size, (rx, ry), (ny, nx)),
                     size_deg=tile_size, pad=pad)
            )
    return tiles


def budget_warning(tiles: list[Tile], budget_bytes: float, bytes_per_pixel: float) -> str | None:
    """A one-line warning naming TILE_SIZE when the largest tile needs more than ``budget_bytes`` of working
    memory at ``bytes_per_pixel`` (it is then done in blocks of rows, a tile far bigger than its images only over
    their footprint: :func:`.observations.footprint`), with the TILE_SIZE that fits; None when every tile fits."""
    if not tiles:
        return None
    big = max(tiles, key=lambda t: t.height * t.width)
    px = big.height * big.width
    if px * bytes_per_pixel <= budget_bytes:
        return None
    rows = max(1, int(budget_bytes // (bytes_per_pixel * big.width)))
    fits = tile_side_deg(big.res_x, budget_bytes, bytes_per_pixel, max_deg=big.size_deg)
    return (f"TILE_SIZE {big.size_deg:g} gives tiles of {big.width:,} x {big.height:,} px, more than one block of the "
            f"{budget_bytes / 2**20:,.0f} MiB memory budget: each is done in blocks of {rows:,} rows (at most "
            f"{math.ceil(big.height / rows):,}: only those its images cover); TILE_SIZE {fits:g} (or ingest's "
            f"default) would fit one block")
