"""Georeferencing exactly as the legacy program saw it (Vision Workbench, 2012).

The legacy program addressed pixels by their *centres*: pixel ``(i, j)`` of a
GeoTIFF whose GDAL geotransform is ``(c, a, 0, f, 0, e)`` lies at

    lon = c + a * (i + 0.5),   lat = f + e * (j + 0.5)

and the inverse maps a lon/lat back to fractional pixel indices on that same
convention (:class:`Geo`, the package's :class:`~lunaralbedo.model.grid.Grid` with
these formulas).  Image "corners" (the numbers in its image/tile lists and every
overlap test) are the centres of the first and last pixels, rounded to float32.

The tile grid (SOURCES.md: grid spacing from the first DRG, 5-pixel padding)
and the crop of the padding at the end are reproduced here as pure functions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from affine import Affine

from ..engine.tiles import tile_name, tile_starts
from ..model.grid import Grid

#: The legacy program padded every tile by this many pixels while solving.
PIXEL_PADDING = 5


class Geo(Grid):
    """A :class:`~lunaralbedo.model.grid.Grid` read with the legacy pixel-centre convention.

    ``c, f`` are the GDAL (pixel-corner) origin, ``a`` and ``e`` the pixel size
    (``e`` negative for north-up rasters).  Adds only the legacy formulas: pixel
    centres ``a * i + (c + a / 2)`` (Vision Workbench's order of operations) and the
    float32 corners of the legacy lists.
    """

    @classmethod
    def from_gdal(cls, transform, width: int, height: int) -> "Geo":
        """From rasterio ``Affine`` coefficients ``(a, b, c, d, e, f)``; rotated rasters are refused."""
        t = tuple(transform)[:6]
        if abs(t[1]) > 0 or abs(t[3]) > 0:
            raise ValueError("rotated rasters are not supported by the legacy grid")
        return cls(Affine(float(t[0]), 0.0, float(t[2]), 0.0, float(t[4]), float(t[5])), (int(height), int(width)))

    # The GDAL names of the transform's coefficients, as the legacy formulas use them.
    c = property(lambda self: self.transform.c, doc="West edge (pixel corner), degrees.")
    a = property(lambda self: self.transform.a, doc="Pixel width, degrees.")
    f = property(lambda self: self.transform.f, doc="North edge (pixel corner), degrees.")
    e = property(lambda self: self.transform.e, doc="Pixel height, degrees (negative: north-up).")

    # Centre-of-pixel convention (VW pixel_to_lonlat / lonlat_to_pixel).
    def lon(self, i):
        return self.a * np.asarray(i, dtype=np.float64) + (self.c + 0.5 * self.a)

    def lat(self, j):
        return self.e * np.asarray(j, dtype=np.float64) + (self.f + 0.5 * self.e)

    def col(self, lon):
        return (np.asarray(lon, dtype=np.float64) - (self.c + 0.5 * self.a)) / self.a

    def row(self, lat):
        return (np.asarray(lat, dtype=np.float64) - (self.f + 0.5 * self.e)) / self.e

    def corners(self) -> tuple[float, float, float, float]:
        """``(west, east, south, north)`` of the first/last pixel centres, as float32 (legacy lists)."""
        x0, x1 = float(self.lon(0)), float(self.lon(self.width - 1))
        y0, y1 = float(self.lat(0)), float(self.lat(self.height - 1))
        w, e = sorted((float(np.float32(x0)), float(np.float32(x1))))
        s, n = sorted((float(np.float32(y0)), float(np.float32(y1))))
        return (w, e, s, n)


def sub_window(geo: Geo, nw: tuple[float, float], se: tuple[float, float], margin: int = 2) -> tuple[int, int, int, int] | None:
    """Legacy getSubImageWithMargin: ``(col0, row0, col1, row1)`` of the part of ``geo`` around the box.

    ``nw``/``se`` are the lon/lat of the box's north-west and south-east pixel centres;
    the window is widened by ``margin`` pixels and clipped to the image (None when empty).
    """
    bc, br = float(geo.col(nw[0])), float(geo.row(nw[1]))
    ec, er = float(geo.col(se[0])), float(geo.row(se[1]))
    c0, c1 = max(0, math.floor(bc) - margin), min(geo.width, math.ceil(ec) + margin)
    r0, r1 = max(0, math.floor(br) - margin), min(geo.height, math.ceil(er) + margin)
    if c0 >= c1 or r0 >= r1:
        return None
    return (c0, r0, c1, r1)


def boxes_overlap(b1, b2) -> bool:
    """Legacy overlap test of ``(west, east, south, north)`` boxes (strict inequalities)."""
    return max(b1[0], b2[0]) < min(b1[1], b2[1]) and max(b1[2], b2[2]) < min(b1[3], b2[3])


def legacy_box(box: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """The simulation box as the legacy parser widened it (whole sphere -> +-360)."""
    lon0, lon1, lat0, lat1 = box
    if lon0 <= -180.0:
        lon0 = min(-360.0, lon0)
    if lon1 >= 180.0:
        lon1 = max(360.0, lon1)
    if lat0 <= -90.0 and lat1 >= 90.0:  # settings.py clamps the legacy -180:180 latitudes to +-90
        lat0, lat1 = -360.0, 360.0
    return (lon0, lon1, lat0, lat1)


@dataclass(frozen=True)
class LegacyTile:
    """One padded legacy tile: name, unpadded bounds and padded georeference."""

    name: str
    min_x: float
    max_x: float
    min_y: float
    max_y: float
    geo: Geo
    pad: int = PIXEL_PADDING

    @property
    def corners(self) -> tuple[float, float, float, float]:
        return self.geo.corners()

    @property
    def crop_window(self) -> tuple[int, int, int, int]:
        """``(col0, row0, ncols, nrows)`` kept on the last iteration (legacy cropImageAndGeoRefInPlace)."""
        g = self.geo
        bc, br = g.col(self.min_x), g.row(self.max_y)
        ec, er = g.col(self.max_x), g.row(self.min_y)
        c0 = max(0, math.ceil(bc))
        r0 = max(0, math.ceil(br))
        c1 = min(g.width, int(_round_half_away(ec)) + 1)
        r1 = min(g.height, int(_round_half_away(er)) + 1)
        return (c0, r0, max(c1 - c0, 0), max(r1 - r0, 0))


def _round_half_away(x: float) -> float:
    """C ``round``: halves away from zero."""
    return math.floor(x + 0.5) if x >= 0 else -math.floor(-x + 0.5)


def tiles_for_images(image_corners, tile_size: float, ref: Geo, pad: int = PIXEL_PADDING) -> list[LegacyTile]:
    """Every tile touching one of the images, in the legacy order (south to north, west to east).

    ``image_corners`` are ``(west, east, south, north)`` of the selected DRGs;
    ``ref`` is the georeference of the first DRG of the folder, whose pixel size
    the tiles take.  ``tile_size`` is used as the float32 the legacy parser stored.
    """
    ts = float(np.float32(tile_size))
    keys = {(y, x) for w, e, s, n in image_corners
            for y in tile_starts(s, n, ts, legacy=True) for x in tile_starts(w, e, ts, legacy=True)}
    tiles = []
    cur = ref
    for min_y, min_x in sorted(keys):
        max_y, max_x = min_y + ts, min_x + ts
        # Legacy applyPaddingToTileCorners: step `pad` pixels from the corner and back to degrees.
        # (the legacy loop moved the reference's origin to each new tile; so do we).
        dx = float(cur.lon(cur.col(min_x) + pad)) - min_x
        dy = float(cur.lat(cur.row(max_y) + pad)) - max_y  # < 0 for north-up
        x0p, x1p = min_x - dx, max_x + dx
        y0p, y1p = min_y + dy, max_y - dy
        ncols = int(_round_half_away((x1p - x0p) / ref.a))
        nrows = int(_round_half_away((y0p - y1p) / ref.e))
        geo = Geo(Affine(ref.a, 0.0, x0p, 0.0, ref.e, y1p), (nrows, ncols))
        cur = geo
        tiles.append(LegacyTile(name=tile_name(min_x, max_y, legacy=True), min_x=min_x, max_x=max_x, min_y=min_y, max_y=max_y, geo=geo, pad=pad))
    return tiles


def unpadded_corners(tile_geo: Geo, tile_size: float, pad: int = PIXEL_PADDING) -> tuple[float, float, float, float]:
    """Legacy getTileCornersWithoutPadding: ``(min_x, max_x, min_y, max_y)`` snapped to the tile size."""
    ts = float(np.float32(tile_size))
    nw_x, nw_y = float(tile_geo.lon(pad)), float(tile_geo.lat(pad))
    se_x, se_y = float(tile_geo.lon(tile_geo.width - 1 - pad)), float(tile_geo.lat(tile_geo.height - 1 - pad))
    r = _round_half_away
    return (ts * r(nw_x / ts), ts * r(se_x / ts), ts * r(se_y / ts), ts * r(nw_y / ts))
