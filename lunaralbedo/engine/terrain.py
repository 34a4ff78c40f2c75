"""Terrain of one tile: the DEM with the margin cast shadows need, and each image's cast shadows (:class:`TileShadows`).

The margin is found from the terrain itself: the DEM is read around the tile, the
longest shadow its relief can cast into the tile with the lowest Sun of the tile's
images is computed (:func:`~lunaralbedo.model.cast_shadows.shadow_reach_km`, curvature
counted), and the DEM is read again with a wider margin while that reach exceeds
the margin (up to :data:`~lunaralbedo.model.cast_shadows.MAX_REACH_KM`).
"""
from __future__ import annotations

import math

import numpy as np
from rasterio.transform import Affine

from ..constants import MOON_RADIUS_KM
from ..io.opened import kept_open
from ..io.rasters import read_dem_onto_grid
from ..model import geometry
from ..model.cast_shadows import MAX_REACH_KM, MarchGrid, shadow_reach_km, sun_elevation

#: Margin (pixels) first read around a tile for cast shadows.
FIRST_MARGIN_PX = 16


#: Rows of the shadow DEM read at a time (bounds the reader's temporaries for big tiles).
READ_ROWS = 256


def _read_into(dem, scene, transform, r0: int, r1: int, c0: int, c1: int) -> None:
    """Read the DEM's rows ``r0:r1``, columns ``c0:c1`` of the grid ``transform`` into ``dem``, :data:`READ_ROWS` at a time."""
    for a in range(r0, r1, READ_ROWS):
        b = min(a + READ_ROWS, r1)
        dem[a:b, c0:c1] = read_dem_onto_grid(scene.dems, transform @ Affine.translation(c0, a), (b - a, c1 - c0),
                                             scene.crs, scene.settings.no_dem_data_val)


def _read(scene, tile, margin: int, inner=None) -> tuple[np.ndarray, Affine]:
    """The DEM (float32) around the tile with ``margin`` pixels.  ``inner``: the DEM with a smaller margin,
    already read: copied, and only the frame around it is read (the same values: each pixel is read on its own)."""
    transform = tile.transform @ Affine.translation(-margin, -margin)
    h, w = tile.height + 2 * margin, tile.width + 2 * margin
    dem = np.empty((h, w), np.float32)
    if inner is None:
        _read_into(dem, scene, transform, 0, h, 0, w)
        return dem, transform
    d = (h - inner.shape[0]) // 2
    dem[d:h - d, d:w - d] = inner
    for r0, r1, c0, c1 in _frame(h, w, d):
        _read_into(dem, scene, transform, r0, r1, c0, c1)
    return dem, transform


def _frame(h: int, w: int, d: int) -> tuple:
    """``(r0, r1, c0, c1)`` of the four parts of an ``h`` x ``w`` grid within ``d`` pixels of its edges."""
    return (0, d, 0, w), (h - d, h, 0, w), (d, h - d, 0, d), (d, h - d, w - d, w)


def _pixel_km(tile) -> float:
    lat = math.radians(tile.north - tile.height * tile.res_y / 2)
    return math.radians(1.0) * MOON_RADIUS_KM * min(tile.res_x * max(math.cos(lat), 1e-3), tile.res_y)


#: Largest cast-shadow DEM (bytes, float32, the tile with its margin) held for a whole tile; a bigger tile holds
#: one band at a time: its block's rows with the margin above and below (:meth:`TileShadows.for_rows`).
#: An 8000 x 8000 px tile under 4 narrow images: peak 812 MB held whole (at 256 MiB), 393 MB banded, as fast;
#: make bench item 10's 4000 x 4000 px tile: 808 MB either way (its blocks dominate), so it stays whole.
WHOLE_DEM_BYTES = 128 * 2**20


class TileShadows:
    """The cast shadows of a tile's images: the DEM read once (with the margin), asked pixel by pixel.

    ``shadowed(k, rows, cols)`` answers for unpadded tile pixels only, so the march runs
    only where an image would otherwise have an observation (the narrow strip of `make bench` item 6
    spent 90 % of its prepare time marching whole tiles per image).

    A tile whose DEM with its margin exceeds :data:`WHOLE_DEM_BYTES` (~5700 x 5700 px and more)
    is *banded*: its margin is found from the terrain read a few rows at a time, and
    :meth:`for_rows` reads, for each block of rows, the band of those rows with the margin
    above and below, so the memory follows the block, not the tile.  A ray is then followed
    up to the margin beyond its block (rather than beyond the tile): the margin is the longest
    shadow the tile's relief casts with the lowest Sun at the tile's centre, so the answers
    are those of the whole tile (``tests/test_terrain_bands.py``), unless the Sun stands
    lower elsewhere in the tile and a shadow is longer than the margin, as at the tile's edges.
    """

    def __init__(self, scene, tile, images, banded: bool | None = None):
        self.scene, self.tile, self.dem = scene, tile, None
        self.banded = False
        if not len(images) or not scene.dems:
            return
        lon_c = tile.west + tile.width * tile.res_x / 2
        lat_c = tile.north - tile.height * tile.res_y / 2
        centre = geometry.body_fixed(lon_c, lat_c, 0.0)
        elev = min(float(sun_elevation(centre, scene.sun[k])) for k in images)
        px_km = _pixel_km(tile)
        max_margin = int(math.ceil(MAX_REACH_KM / px_km)) + 2
        if banded is None:
            side = 2 * FIRST_MARGIN_PX
            banded = (tile.height + side) * (tile.width + side) * 4 > WHOLE_DEM_BYTES
        if banded:
            self.margin = _banded_margin(scene, tile, elev, px_km, max_margin)
            self.banded = self.margin is not None
            return
        margin = FIRST_MARGIN_PX
        dem = None
        with kept_open():  # the DEM files stay open over the chunks: each compressed block decoded once
            while True:
                dem, transform = _read(scene, tile, margin, dem)
                inner = dem[margin:margin + tile.height, margin:margin + tile.width]
                if not np.isfinite(inner).any():
                    return
                wider = _wider_margin(float(np.nanmax(dem) - np.nanmin(inner)), elev, px_km, margin, max_margin)
                if wider is None:
                    break
                margin = wider
        self._hold(dem, transform, margin, 0)

    def _hold(self, dem, transform, margin: int, row0: int, band=None) -> None:
        self.dem = dem  # float32: the march gives the answers of float64 heights
        self.grid = MarchGrid(dem, transform, band=band)  # tables shared by all images (the pyramid built on first need)
        self.transform, self.margin, self.row0 = transform, margin, row0

    def for_rows(self, b0: int, b1: int) -> "TileShadows":
        """The cast shadows of the tile's rows ``b0:b1``: the tile's own (not banded), else the band of those rows
        with the margin above and below, read now (:meth:`rows` and :meth:`shadowed` take tile rows as ever)."""
        if not self.banded:
            return self
        band = object.__new__(TileShadows)
        band.scene, band.tile, band.banded = self.scene, self.tile, False
        m, tile = self.margin, self.tile
        transform = tile.transform @ Affine.translation(-m, b0 - m)
        dem = np.empty((b1 - b0 + 2 * m, tile.width + 2 * m), np.float32)
        with kept_open():
            _read_into(dem, self.scene, transform, 0, dem.shape[0], 0, dem.shape[1])
        whole = tile.transform @ Affine.translation(-m, -m)  # the grid of the whole tile's DEM, whose rows b0: these are
        band._hold(dem, transform, m, b0, band=(whole, b0, tile.height + 2 * m))
        return band

    def rows(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """The DEM (float32) of unpadded tile rows ``r0:r1``, columns ``c0:c1`` (may reach into the margin)."""
        m, b = self.margin, self.row0
        return self.dem[r0 - b + m:r1 - b + m, c0 + m:c1 + m]

    def shadowed(self, k: int, rows, cols, row0: int = 0, col0: int = 0) -> np.ndarray:
        """True where unpadded tile pixel ``(row0 + rows[o], col0 + cols[o])`` is in image ``k``'s cast shadow."""
        if self.dem is None:
            return np.zeros(np.shape(rows), bool)
        return self.grid.march(self.scene.sun[k], rows, cols,
                               offset=(self.margin + row0 - self.row0, self.margin + col0))


def _wider_margin(relief_m: float, elev: float, px_km: float, margin: int, max_margin: int) -> int | None:
    """The next margin to read when the longest shadow of ``relief_m`` with the Sun ``elev`` (rad) high needs more
    pixels than ``margin`` (the need, at least twice the margin, at most ``max_margin``); None when it does not."""
    need = int(math.ceil(shadow_reach_km(relief_m, elev) / px_km)) + 2
    if need <= margin or margin >= max_margin:
        return None
    return min(max(need, 2 * margin), max_margin)


def _banded_margin(scene, tile, elev: float, px_km: float, max_margin: int) -> int | None:
    """The margin :class:`TileShadows` finds for the whole tile, from the DEM read :data:`READ_ROWS` rows at a time
    (its highest height with the margin, its lowest inside the tile; the frame read again as the margin widens);
    None when the tile has no height."""
    h, w = tile.height, tile.width
    hi, lo, margin, inner = -np.inf, np.inf, FIRST_MARGIN_PX, 0
    with kept_open():
        while True:
            transform = tile.transform @ Affine.translation(-margin, -margin)
            hm, wm = h + 2 * margin, w + 2 * margin  # the frame between the margin read before (inner) and this one
            parts = [(0, hm, 0, wm)] if inner == 0 else _frame(hm, wm, margin - inner)
            for r0, r1, c0, c1 in parts:
                for a in range(r0, r1, READ_ROWS):
                    b = min(a + READ_ROWS, r1)
                    chunk = np.empty((b - a, c1 - c0), np.float32)
                    _read_into(chunk, scene, transform @ Affine.translation(c0, a), 0, b - a, 0, c1 - c0)
                    if np.isfinite(chunk).any():
                        hi = max(hi, float(np.nanmax(chunk)))
                        if inner == 0:  # the first read: the tile's own rows and columns give the lowest height
                            core = chunk[max(margin - a, 0):max(min(margin + h - a, b - a), 0), margin:margin + w]
                            if np.isfinite(core).any():
                                lo = min(lo, float(np.nanmin(core)))
            if not np.isfinite(lo):
                return None
            wider = _wider_margin(hi - lo, elev, px_km, margin, max_margin)
            if wider is None:
                return margin
            inner, margin = margin, wider
