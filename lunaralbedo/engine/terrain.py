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
    for r0, r1, c0, c1 in ((0, d, 0, w), (h - d, h, 0, w), (d, h - d, 0, d), (d, h - d, w - d, w)):
        _read_into(dem, scene, transform, r0, r1, c0, c1)
    return dem, transform


def _pixel_km(tile) -> float:
    lat = math.radians(tile.north - tile.height * tile.res_y / 2)
    return math.radians(1.0) * MOON_RADIUS_KM * min(tile.res_x * max(math.cos(lat), 1e-3), tile.res_y)


class TileShadows:
    """The cast shadows of a tile's images: the DEM read once (with the margin), asked pixel by pixel.

    ``shadowed(k, rows, cols)`` answers for unpadded tile pixels only, so the march runs
    only where an image would otherwise have an observation (the narrow strip of issue 15
    spent 90 % of its prepare time marching whole tiles per image).
    """

    def __init__(self, scene, tile, images):
        self.scene, self.dem = scene, None
        if not len(images) or not scene.dems:
            return
        lon_c = tile.west + tile.width * tile.res_x / 2
        lat_c = tile.north - tile.height * tile.res_y / 2
        centre = geometry.body_fixed(lon_c, lat_c, 0.0)
        elev = min(float(sun_elevation(centre, scene.sun[k])) for k in images)
        px_km = _pixel_km(tile)
        max_margin = int(math.ceil(MAX_REACH_KM / px_km)) + 2
        margin = FIRST_MARGIN_PX
        dem = None
        with kept_open():  # the DEM files stay open over the chunks: each compressed block decoded once
            while True:
                dem, transform = _read(scene, tile, margin, dem)
                inner = dem[margin:margin + tile.height, margin:margin + tile.width]
                if not np.isfinite(inner).any():
                    return
                relief = float(np.nanmax(dem) - np.nanmin(inner))
                need = int(math.ceil(shadow_reach_km(relief, elev) / px_km)) + 2
                if need <= margin or margin >= max_margin:
                    break
                margin = min(max(need, 2 * margin), max_margin)
        self.dem = dem  # float32: the march gives the answers of float64 heights
        self.grid = MarchGrid(dem, transform)  # tables shared by all images (the pyramid built on first need)
        self.transform, self.margin = transform, margin

    def rows(self, r0: int, r1: int, c0: int, c1: int) -> np.ndarray:
        """The DEM (float32) of unpadded tile rows ``r0:r1``, columns ``c0:c1`` (may reach into the margin)."""
        m = self.margin
        return self.dem[r0 + m:r1 + m, c0 + m:c1 + m]

    def shadowed(self, k: int, rows, cols, row0: int = 0, col0: int = 0) -> np.ndarray:
        """True where unpadded tile pixel ``(row0 + rows[o], col0 + cols[o])`` is in image ``k``'s cast shadow."""
        if self.dem is None:
            return np.zeros(np.shape(rows), bool)
        return self.grid.march(self.scene.sun[k], rows, cols, offset=(self.margin + row0, self.margin + col0))
